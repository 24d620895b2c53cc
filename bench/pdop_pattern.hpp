// The content of the benchmark's PDO Packets, shared by bench/pdop_source and bench/pdop_sink so
// that the sink can tell an intact packet from a short, merged or corrupted one.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace canbridge::bench {

// Packet `index` of `size` bytes (size >= 4): the index as a little-endian u32, then bytes that
// depend on the index and the position, so that a packet missing an even number of fragments (which
// one toggle bit cannot see, docs/pdop.md section 7) or two packets merged fail the check.
inline std::uint8_t pattern_byte(std::uint32_t index, std::size_t position) {
  if (position < 4) return static_cast<std::uint8_t>(index >> (8 * position));
  return static_cast<std::uint8_t>(index * 131u + position * 7u + 1u);
}

inline std::vector<std::uint8_t> make_packet(std::uint32_t index, std::size_t size) {
  std::vector<std::uint8_t> packet(size);
  for (std::size_t i = 0; i < size; ++i) packet[i] = pattern_byte(index, i);
  return packet;
}

// The packet's index when it has exactly `size` bytes and every byte matches; -1 otherwise.
inline std::int64_t check_packet(std::span<const std::uint8_t> packet, std::size_t size) {
  if (packet.size() != size || size < 4) return -1;
  const std::uint32_t index = std::uint32_t{packet[0]} | std::uint32_t{packet[1]} << 8 |
                              std::uint32_t{packet[2]} << 16 | std::uint32_t{packet[3]} << 24;
  for (std::size_t i = 4; i < size; ++i) {
    if (packet[i] != pattern_byte(index, i)) return -1;
  }
  return index;
}

}  // namespace canbridge::bench
