// The CiA 305 LSS wire format both ends share (command specifiers, answer codes, the LSS
// address), so the master (canopen/lss_master) and the simulated slave (sim/lss_slave) agree.
#pragma once

#include <cstdint>

namespace canbridge::canopen::lss {

// Every LSS frame has 8 data bytes: byte 0 the command specifier, the rest its arguments
// (UNSIGNED32 little-endian in bytes 1..4 for identity values). Requests on cob::lss_master
// (0x7E5), answers on cob::lss_slave (0x7E4).
inline constexpr std::uint8_t switch_global = 0x04;  // byte 1: 0 waiting, 1 configuration
inline constexpr std::uint8_t switch_selective_vendor = 0x40;
inline constexpr std::uint8_t switch_selective_product = 0x41;
inline constexpr std::uint8_t switch_selective_revision = 0x42;
inline constexpr std::uint8_t switch_selective_serial = 0x43;
inline constexpr std::uint8_t switch_selective_answer = 0x44;
inline constexpr std::uint8_t configure_node_id = 0x11;  // byte 1: 1..127 or 0xFF
inline constexpr std::uint8_t configure_bit_timing = 0x13;
inline constexpr std::uint8_t store_configuration = 0x17;
inline constexpr std::uint8_t inquire_vendor = 0x5A;
inline constexpr std::uint8_t inquire_product = 0x5B;
inline constexpr std::uint8_t inquire_revision = 0x5C;
inline constexpr std::uint8_t inquire_serial = 0x5D;
inline constexpr std::uint8_t inquire_node_id = 0x5E;

inline constexpr std::uint8_t unconfigured_node_id = 0xFF;

// Byte 1 of the configure and store answers (byte 2: the implementation's own code when 0xFF).
inline constexpr std::uint8_t answer_success = 0;
inline constexpr std::uint8_t answer_node_id_out_of_range = 1;  // configure node-id
inline constexpr std::uint8_t answer_not_supported = 1;         // store, bit timing
inline constexpr std::uint8_t answer_storage_access = 2;        // store
inline constexpr std::uint8_t answer_implementation_specific = 0xFF;

// The LSS address: the four values of 1018h (identity object).
struct Address {
  std::uint32_t vendor = 0;
  std::uint32_t product = 0;
  std::uint32_t revision = 0;
  std::uint32_t serial = 0;
  friend bool operator==(const Address&, const Address&) = default;
};

}  // namespace canbridge::canopen::lss
