#include "canopen/lss_master.hpp"

#include <array>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>

#include "canopen/little_endian.hpp"

namespace canbridge::canopen {

namespace {

class LssCategory : public std::error_category {
 public:
  const char* name() const noexcept override { return "canopen.lss"; }
  std::string message(int value) const override {
    switch (static_cast<LssError>(value)) {
      case LssError::timeout:
        return "no LSS answer in time";
      case LssError::node_id_out_of_range:
        return "LSS slave: node-ID out of range";
      case LssError::not_supported:
        return "LSS slave: service not supported";
      case LssError::storage_access:
        return "LSS slave: storage media access error";
      case LssError::implementation_specific:
        return "LSS slave: implementation-specific error";
      case LssError::refused:
        return "LSS slave: refused (reserved error code)";
    }
    return "unknown LSS error " + std::to_string(value);
  }
};

can::Frame request(std::uint8_t command, std::uint32_t value = 0) {
  std::array<std::uint8_t, 8> data{command};
  store_le(value, std::span<std::uint8_t>(data).subspan(1, 4));
  return can::Frame::from_span(cob::lss_master, data);
}

// The error of a configure / store answer's code (byte 1).
std::error_code answer_error(std::uint8_t command, std::uint8_t code) {
  switch (code) {
    case lss::answer_success:
      return {};
    case 1:
      return command == lss::configure_node_id ? LssError::node_id_out_of_range
                                               : LssError::not_supported;
    case lss::answer_storage_access:
      if (command == lss::store_configuration) return LssError::storage_access;
      return LssError::refused;
    case lss::answer_implementation_specific:
      return LssError::implementation_specific;
    default:
      return LssError::refused;
  }
}

}  // namespace

const std::error_category& lss_category() noexcept {
  static const LssCategory category;
  return category;
}

std::error_code make_error_code(LssError error) noexcept {
  return {static_cast<int>(error), lss_category()};
}

LssMaster::LssMaster(std::vector<can::Frame> requests, std::uint8_t answer,
                     std::chrono::milliseconds timeout)
    : requests_(std::move(requests)), answer_(answer), timeout_(timeout) {}

LssMaster LssMaster::switch_global(bool configuration, std::chrono::milliseconds timeout) {
  return LssMaster({request(lss::switch_global, configuration ? 1 : 0)}, 0, timeout);
}

LssMaster LssMaster::switch_selective(const lss::Address& address,
                                      std::chrono::milliseconds timeout) {
  return LssMaster({request(lss::switch_selective_vendor, address.vendor),
                    request(lss::switch_selective_product, address.product),
                    request(lss::switch_selective_revision, address.revision),
                    request(lss::switch_selective_serial, address.serial)},
                   lss::switch_selective_answer, timeout);
}

LssMaster LssMaster::configure_node_id(std::uint8_t node_id, std::chrono::milliseconds timeout) {
  if ((node_id == 0 || node_id > kMaxNodeId) && node_id != lss::unconfigured_node_id) {
    throw std::invalid_argument("LSS configure node-id: outside 1..127 and not 0xFF");
  }
  return LssMaster({request(lss::configure_node_id, node_id)}, lss::configure_node_id, timeout);
}

LssMaster LssMaster::store_configuration(std::chrono::milliseconds timeout) {
  return LssMaster({request(lss::store_configuration)}, lss::store_configuration, timeout);
}

LssMaster LssMaster::inquire(LssInquiry what, std::chrono::milliseconds timeout) {
  const std::uint8_t command =
      what == LssInquiry::node_id
          ? lss::inquire_node_id
          : static_cast<std::uint8_t>(lss::inquire_vendor + static_cast<std::uint8_t>(what));
  return LssMaster({request(command)}, command, timeout);
}

void LssMaster::start(TimePoint now, std::vector<can::Frame>& out) {
  if (finished_ || deadline_ != TimePoint::max()) return;
  out.insert(out.end(), requests_.begin(), requests_.end());
  if (answer_ == 0) {
    finish({});
    return;
  }
  deadline_ = now + timeout_;
}

void LssMaster::on_frame(const can::Frame& frame, TimePoint /*now*/) {
  if (finished_ || deadline_ == TimePoint::max()) return;
  if (!frame.is_standard_data() || frame.id != cob::lss_slave || frame.len < 1) return;
  if (frame.data[0] != answer_) return;
  LssResult result;
  switch (answer_) {
    case lss::configure_node_id:
    case lss::store_configuration:
      result.answer_code = frame.data[1];
      result.specific_code = frame.data[2];
      result.error = answer_error(answer_, frame.data[1]);
      break;
    case lss::inquire_node_id:
      result.value = frame.data[1];
      break;
    case lss::switch_selective_answer:
      break;
    default:  // identity inquiries
      result.value = load_le32(frame.payload().subspan(1));
      break;
  }
  finish(std::move(result));
}

void LssMaster::on_timeout(TimePoint now) {
  if (finished_ || now < deadline_) return;
  finish({LssError::timeout, 0, 0, 0});
}

void LssMaster::finish(LssResult result) {
  finished_ = true;
  result_ = std::move(result);
}

}  // namespace canbridge::canopen
