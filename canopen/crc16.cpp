#include "canopen/crc16.hpp"

#include <array>

namespace canbridge::canopen {

namespace {

// One entry per leading byte: block transfers checksum up to megabytes, so the bitwise loop runs
// once per table entry at compile time instead of once per data bit.
constexpr std::array<std::uint16_t, 256> make_table() {
  std::array<std::uint16_t, 256> table{};
  for (std::uint32_t byte = 0; byte < 256; ++byte) {
    std::uint32_t crc = byte << 8;
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc & 0x8000) != 0 ? (crc << 1) ^ 0x1021 : crc << 1;
    }
    table[byte] = static_cast<std::uint16_t>(crc);
  }
  return table;
}

constexpr auto kTable = make_table();

}  // namespace

std::uint16_t crc16_xmodem(std::span<const std::uint8_t> data, std::uint16_t crc) {
  for (const std::uint8_t byte : data) {
    crc = static_cast<std::uint16_t>(crc << 8 ^ kTable[(crc >> 8 ^ byte) & 0xFF]);
  }
  return crc;
}

}  // namespace canbridge::canopen
