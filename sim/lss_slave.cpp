#include "sim/lss_slave.hpp"

#include <array>
#include <span>

#include "canopen/little_endian.hpp"

namespace canbridge::sim {

namespace lss = canopen::lss;

LssSlave::LssSlave(LssSlaveOptions options) : options_(options) {}

std::optional<canopen::NodeId> LssSlave::pending_node_id() const {
  // Unconfiguring (0xFF) has no meaning for a simulated node that always runs with an id.
  if (pending_ == lss::unconfigured_node_id || pending_ == options_.active_node_id) {
    return std::nullopt;
  }
  return pending_;
}

// Configure / store answers carry their error code in byte 1, inquiries their value in 1..4.
void LssSlave::answer(std::uint8_t command, std::uint32_t value,
                      std::vector<can::Frame>& out) const {
  std::array<std::uint8_t, 8> data{command};
  canopen::store_le(value, std::span<std::uint8_t>(data).subspan(1, 4));
  out.push_back(can::Frame::from_span(canopen::cob::lss_slave, data));
}

void LssSlave::on_frame(const can::Frame& frame, std::vector<can::Frame>& out) {
  // CiA 305 requests always carry 8 bytes; anything shorter is not for an LSS slave.
  if (!frame.is_standard_data() || frame.id != canopen::cob::lss_master || frame.len != 8) return;
  const std::uint8_t command = frame.data[0];
  const std::uint32_t value = canopen::load_le32(frame.payload().subspan(1, 4));
  const lss::Address& own = options_.address;
  switch (command) {
    case lss::switch_global:
      if (frame.data[1] <= 1) {
        configuration_ = frame.data[1] == 1;
        selective_next_ = 0;
      }
      return;
    case lss::switch_selective_vendor:
    case lss::switch_selective_product:
    case lss::switch_selective_revision:
    case lss::switch_selective_serial: {
      if (configuration_) return;  // only a waiting slave is selected
      const int step = command - lss::switch_selective_vendor;
      const std::uint32_t expected[] = {own.vendor, own.product, own.revision, own.serial};
      // The vendor starts a new selection; each later part must follow its predecessor.
      if (step == 0) selective_next_ = 0;
      if (selective_next_ != step || value != expected[step]) {
        selective_next_ = -1;
        return;
      }
      selective_next_ = step + 1;
      if (step == 3) {
        selective_next_ = 0;
        configuration_ = true;
        answer(lss::switch_selective_answer, 0, out);
      }
      return;
    }
    default:
      break;
  }
  if (!configuration_) return;  // every other service needs the configuration state
  switch (command) {
    case lss::configure_node_id: {
      const std::uint8_t id = frame.data[1];
      const bool valid = (id >= 1 && id <= canopen::kMaxNodeId) || id == lss::unconfigured_node_id;
      if (valid) pending_ = id;
      answer(command, valid ? lss::answer_success : lss::answer_node_id_out_of_range, out);
      return;
    }
    case lss::configure_bit_timing:
      answer(command, lss::answer_not_supported, out);
      return;
    case lss::store_configuration:
      if (!options_.store_supported) {
        answer(command, lss::answer_not_supported, out);
        return;
      }
      stored_ = pending_ != lss::unconfigured_node_id ? pending_ : options_.active_node_id;
      answer(command, lss::answer_success, out);
      return;
    case lss::inquire_vendor:
      answer(command, own.vendor, out);
      return;
    case lss::inquire_product:
      answer(command, own.product, out);
      return;
    case lss::inquire_revision:
      answer(command, own.revision, out);
      return;
    case lss::inquire_serial:
      answer(command, own.serial, out);
      return;
    case lss::inquire_node_id:
      answer(command, options_.active_node_id, out);
      return;
    default:
      return;  // identify services and the rest are not simulated
  }
}

}  // namespace canbridge::sim
