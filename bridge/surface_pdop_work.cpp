#include "bridge/surface_pdop_work.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>

namespace canbridge::bridge {

SurfacePdopWork::SurfacePdopWork(RpdopRelayOptions relay_options) : relay_(relay_options) {}

bool SurfacePdopWork::announced(const From& from, std::uint32_t module_id) const {
  return std::find(from.modules.begin(), from.modules.end(), module_id) != from.modules.end();
}

void SurfacePdopWork::on_nodes(const From& from, const v1::PdopNodes& nodes) {
  for (const v1::PdopNodes::Node& n : nodes.nodes()) {
    if (n.surface_node() < 1 || n.surface_node() > canopen::pdop::kMaxNode ||
        !announced(from, n.module_id()) ||
        !from.speaks_for(static_cast<canopen::NodeId>(n.surface_node()))) {
      ++counters_.malformed;
      continue;
    }
    const auto node = static_cast<canopen::NodeId>(n.surface_node());
    owner_[node] = {from.id, n.module_id()};
    relay_.set_relayed(node, n.whole());
    fragments_as_frames_[node] = !n.whole();
  }
  const auto whole = std::count_if(nodes.nodes().begin(), nodes.nodes().end(),
                                   [](const v1::PdopNodes::Node& n) { return n.whole(); });
  spdlog::info("surface: gateway '{}' has {} pdop node(s), {} carrying PDO Packets whole",
               from.name, nodes.nodes_size(), whole);
}

PdopPacketToBus SurfacePdopWork::on_packet(const From& from, const v1::PdopPacket& packet) {
  PdopPacketToBus to_bus =
      surface_pdop_packet(packet, announced(from, packet.module_id()), from.speaks_for);
  if (to_bus.verdict == PdopPacketToBus::Verdict::cannot_be_put) {
    ++counters_.malformed;
    warn_.warn(Warn::kMalformed,
               "surface: gateway '{}' sent a PDO Packet with module {} node {} TPDO {} and {} "
               "bytes, which cannot be put on the bus: dropped (counted)",
               from.name, packet.module_id(), packet.surface_node(), packet.pdo(),
               packet.data().size());
  }
  return to_bus;
}

void SurfacePdopWork::delivered(const From& from, const v1::PdopPacket& packet) {
  ++counters_.packets;
  counters_.packet_bytes += packet.data().size();
  if (!packet.probable_repeat()) return;
  ++counters_.probable_repeats;
  warn_.warn(Warn::kRepeat,
             "surface: gateway '{}' node {} TPDO{}: a one-frame packet repeating the last "
             "fragment of the packet before it, probably received twice on the module bus; "
             "delivered all the same (counted as probable-repeats)",
             from.name, packet.surface_node(), packet.pdo());
}

void SurfacePdopWork::on_reports(const From& from, const v1::PdopReports& reports) {
  for (const v1::PdopDiscard& d : reports.discards()) {
    ++counters_.discards;
    warn_.warn(Warn::kDiscard,
               "surface: gateway '{}' module {} node {} (surface {}) TPDO{}: broken PDO Packet "
               "discarded ({}, after {} fragments) (counted; later ones only in the counters)",
               from.name, d.module_id(), d.local_node(), d.surface_node(), d.tpdo(),
               v1::PdopDiscard::Reason_Name(d.reason()), d.fragments());
  }
  for (const v1::RpdopOutcome& o : reports.outcomes()) {
    const canopen::pdop::AckStatus status = rpdop_ack_status(o);
    if (status == canopen::pdop::AckStatus::complete) {
      ++counters_.rpdop_complete;
    } else {
      ++counters_.rpdop_failed;
      warn_.warn(
          Warn::kRpdopFailed,
          "surface: gateway '{}' node {} RPDO{}: packet not delivered ({}, status 0x{:02X}); "
          "the master sees the status (counted; later ones only in the counters)",
          from.name, o.surface_node(), o.rpdo(), v1::RpdopOutcome::Result_Name(o.result()),
          o.status());
    }
    relay_.on_outcome(o.request_id(), status, relay_out_);
  }
}

bool SurfacePdopWork::on_bus_frame(const can::Frame& frame, TimePoint now) {
  return relay_.on_frame(frame, now, relay_out_);
}

void SurfacePdopWork::tick(TimePoint now) {
  relay_.tick(now, relay_out_);
}

SurfacePdopWork::Output& SurfacePdopWork::flush(const std::function<bool(GatewayId)>& link_up) {
  out_.payloads.clear();
  out_.frames.clear();
  // Taken out first: answering a packet at once (link down) appends its acknowledgement to
  // relay_out_.frames, after those already there.
  std::vector<RpdopRelay::Packet> packets;
  packets.swap(relay_out_.packets);
  for (RpdopRelay::Packet& packet : packets) {
    const Owner& owner = owner_[packet.node & canopen::pdop::kMaxNode];
    if (!owner.gateway || !link_up(*owner.gateway)) {
      // The master learns at once: its packet cannot reach the node now (0x82, no room).
      ++counters_.rpdop_failed;
      relay_.on_outcome(packet.request_id, canopen::pdop::AckStatus::out_of_memory, relay_out_);
      continue;
    }
    v1::Payload payload;
    v1::PdopPacket& p = *payload.mutable_pdop_packets()->add_packets();
    p.set_module_id(owner.module_id);
    p.set_surface_node(packet.node);
    p.set_pdo(packet.rpdo);
    p.set_data(packet.bytes.data(), packet.bytes.size());
    p.set_request_id(packet.request_id);
    out_.payloads.emplace_back(*owner.gateway, payload.SerializeAsString());
    ++counters_.rpdop_forwarded;
  }
  out_.frames.swap(relay_out_.frames);
  return out_;
}

}  // namespace canbridge::bridge
