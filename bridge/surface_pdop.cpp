#include "bridge/surface_pdop.hpp"

namespace canbridge::bridge {

PdopPacketToBus surface_pdop_packet(const v1::PdopPacket& packet, bool announced,
                                    const std::function<bool(canopen::NodeId)>& speaks_for) {
  PdopPacketToBus out;
  const std::uint16_t base = canopen::pdop::tpdo_base(packet.pdo());
  if (!announced || base == 0 || packet.surface_node() < 1 ||
      packet.surface_node() > canopen::pdop::kMaxNode) {
    return out;
  }
  const auto node = static_cast<canopen::NodeId>(packet.surface_node());
  out.cob_id = base + node;
  if (!speaks_for(node)) {
    out.verdict = PdopPacketToBus::Verdict::not_its_own;
    return out;
  }
  const std::string& data = packet.data();
  out.fragments =
      canopen::pdop::fragment(base, node,
                              std::span<const std::uint8_t>(
                                  reinterpret_cast<const std::uint8_t*>(data.data()), data.size()));
  if (!out.fragments.empty()) out.verdict = PdopPacketToBus::Verdict::to_bus;
  return out;
}

canopen::pdop::AckStatus rpdop_ack_status(const v1::RpdopOutcome& outcome) {
  using canopen::pdop::AckStatus;
  switch (outcome.result()) {
    case v1::RpdopOutcome::COMPLETE:
      return AckStatus::complete;
    case v1::RpdopOutcome::RECEIVER_ABORT:
      return outcome.status() >= 0x80 && outcome.status() <= 0xFF
                 ? static_cast<AckStatus>(outcome.status())
                 : AckStatus::out_of_memory;
    case v1::RpdopOutcome::TIMEOUT:
      return AckStatus::timeout;
    case v1::RpdopOutcome::REFUSED_SIZE:
      return AckStatus::oversize;
    default:  // busy, cancelled, no such node: the node could not take it
      return AckStatus::out_of_memory;
  }
}

}  // namespace canbridge::bridge
