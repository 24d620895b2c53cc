#include "canopen/sdo_abort.hpp"

#include <cstdio>
#include <string>

namespace canbridge::canopen {

namespace {

const char* describe(SdoAbort abort) {
  switch (abort) {
    case SdoAbort::toggle_bit:
      return "toggle bit not alternated";
    case SdoAbort::timeout:
      return "SDO protocol timed out";
    case SdoAbort::invalid_command:
      return "client/server command specifier not valid or unknown";
    case SdoAbort::invalid_block_size:
      return "invalid block size";
    case SdoAbort::invalid_sequence:
      return "invalid sequence number";
    case SdoAbort::crc_error:
      return "CRC error";
    case SdoAbort::out_of_memory:
      return "out of memory";
    case SdoAbort::unsupported_access:
      return "unsupported access to an object";
    case SdoAbort::read_write_only:
      return "attempt to read a write-only object";
    case SdoAbort::write_read_only:
      return "attempt to write a read-only object";
    case SdoAbort::no_object:
      return "object does not exist in the object dictionary";
    case SdoAbort::not_mappable:
      return "object cannot be mapped to the PDO";
    case SdoAbort::pdo_too_long:
      return "number and length of the mapped objects would exceed the PDO length";
    case SdoAbort::parameter_incompatible:
      return "general parameter incompatibility";
    case SdoAbort::device_incompatible:
      return "general internal incompatibility in the device";
    case SdoAbort::hardware_error:
      return "access failed due to a hardware error";
    case SdoAbort::length_mismatch:
      return "data type does not match, length of service parameter does not match";
    case SdoAbort::length_too_high:
      return "data type does not match, length of service parameter too high";
    case SdoAbort::length_too_low:
      return "data type does not match, length of service parameter too low";
    case SdoAbort::no_sub_index:
      return "sub-index does not exist";
    case SdoAbort::value_range:
      return "invalid value for parameter";
    case SdoAbort::value_too_high:
      return "value of parameter written too high";
    case SdoAbort::value_too_low:
      return "value of parameter written too low";
    case SdoAbort::max_below_min:
      return "maximum value is less than minimum value";
    case SdoAbort::resource_unavailable:
      return "resource not available: SDO connection";
    case SdoAbort::general:
      return "general error";
    case SdoAbort::cannot_transfer:
      return "data cannot be transferred or stored to the application";
    case SdoAbort::local_control:
      return "data cannot be transferred or stored to the application because of local control";
    case SdoAbort::device_state:
      return "data cannot be transferred or stored to the application because of the present "
             "device state";
    case SdoAbort::no_dictionary:
      return "object dictionary dynamic generation failed or no object dictionary is present";
  }
  return nullptr;
}

class SdoCategory final : public std::error_category {
 public:
  const char* name() const noexcept override { return "canopen.sdo"; }

  std::string message(int value) const override {
    const auto code = static_cast<std::uint32_t>(value);
    char hex[16];
    std::snprintf(hex, sizeof hex, "%08X", code);
    const char* text = describe(static_cast<SdoAbort>(code));
    if (text == nullptr) return std::string("unknown SDO abort code 0x") + hex;
    return std::string(text) + " (0x" + hex + ")";
  }
};

}  // namespace

const std::error_category& sdo_category() noexcept {
  static const SdoCategory category;
  return category;
}

std::error_code make_error_code(SdoAbort abort) noexcept {
  return {static_cast<int>(abort), sdo_category()};
}

std::uint32_t to_abort_code(std::error_code error) noexcept {
  if (error.category() == sdo_category()) return static_cast<std::uint32_t>(error.value());
  if (error == std::errc::timed_out) return static_cast<std::uint32_t>(SdoAbort::timeout);
  return static_cast<std::uint32_t>(SdoAbort::general);
}

}  // namespace canbridge::canopen
