// SDO abort codes (CiA 301, table of abort codes) as std::error_code values in the "canopen.sdo"
// category, so an abort from the wire and a local protocol failure compare the same way.
#pragma once

#include <cstdint>
#include <system_error>
#include <type_traits>

namespace canbridge::canopen {

// Values are the 32-bit codes carried in bytes 4..7 of an SDO abort frame. Every code is below
// 2^31, so it survives the int of std::error_code unchanged. Their texts are the category's
// messages. 0x0609003x and 0x060A0023 are listed too: real devices send them.
enum class SdoAbort : std::uint32_t {
  toggle_bit = 0x05030000,
  timeout = 0x05040000,
  invalid_command = 0x05040001,
  invalid_block_size = 0x05040002,
  invalid_sequence = 0x05040003,
  crc_error = 0x05040004,
  out_of_memory = 0x05040005,
  unsupported_access = 0x06010000,
  read_write_only = 0x06010001,
  write_read_only = 0x06010002,
  no_object = 0x06020000,
  not_mappable = 0x06040041,
  pdo_too_long = 0x06040042,
  parameter_incompatible = 0x06040043,
  device_incompatible = 0x06040047,
  hardware_error = 0x06060000,
  length_mismatch = 0x06070010,
  length_too_high = 0x06070012,
  length_too_low = 0x06070013,
  no_sub_index = 0x06090011,
  value_range = 0x06090030,
  value_too_high = 0x06090031,
  value_too_low = 0x06090032,
  max_below_min = 0x06090036,
  resource_unavailable = 0x060A0023,
  general = 0x08000000,
  cannot_transfer = 0x08000020,
  local_control = 0x08000021,
  device_state = 0x08000022,
  no_dictionary = 0x08000023,
};

const std::error_category& sdo_category() noexcept;

std::error_code make_error_code(SdoAbort abort) noexcept;

// The 32-bit code to put on the wire for a failure: the code itself for SDO-category errors,
// timeout for a timed-out wait, and the general error 0x08000000 for anything else.
std::uint32_t to_abort_code(std::error_code error) noexcept;

// The error_code for a code received from the wire; unknown codes keep their value (the
// category's message names them as unknown).
inline std::error_code abort_error(std::uint32_t code) noexcept {
  return make_error_code(static_cast<SdoAbort>(code));
}

}  // namespace canbridge::canopen

template <>
struct std::is_error_code_enum<canbridge::canopen::SdoAbort> : std::true_type {};
