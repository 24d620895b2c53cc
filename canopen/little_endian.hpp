// Little-endian integers as CANopen carries them in frames and object values (CiA 301: least
// significant byte first): the one reader and writer every codec and dictionary uses.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>

namespace canbridge::canopen {

// The value of the first min(size, 8) bytes, least significant first; 0 for no bytes.
constexpr std::uint64_t load_le(std::span<const std::uint8_t> bytes) {
  std::uint64_t value = 0;
  const std::size_t n = std::min<std::size_t>(bytes.size(), 8);
  for (std::size_t i = 0; i < n; ++i) value |= static_cast<std::uint64_t>(bytes[i]) << (8 * i);
  return value;
}

// The first min(size, 4) bytes as UNSIGNED32 (shorter values are zero-extended).
constexpr std::uint32_t load_le32(std::span<const std::uint8_t> bytes) {
  return static_cast<std::uint32_t>(load_le(bytes.first(std::min<std::size_t>(bytes.size(), 4))));
}

// Writes the low min(size, 8) bytes of `value` into `out`, least significant first.
constexpr void store_le(std::uint64_t value, std::span<std::uint8_t> out) {
  const std::size_t n = std::min<std::size_t>(out.size(), 8);
  for (std::size_t i = 0; i < n; ++i) out[i] = static_cast<std::uint8_t>(value >> (8 * i));
}

}  // namespace canbridge::canopen
