// Little-endian integers in byte buffers (the serial frame's CRC, the CRC's slicing loop): the
// value does not depend on the host's byte order or the pointer's alignment.
#pragma once

#include <cstdint>

namespace canbridge::backbone {

// Assembled byte by byte; compilers turn this into a single load on little-endian targets.
inline std::uint32_t load_le32(const std::uint8_t* p) {
  return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
         (std::uint32_t{p[3]} << 24);
}

}  // namespace canbridge::backbone
