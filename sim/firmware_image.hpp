// The firmware image format the simulated qd loader accepts: the application bytes followed by
// their CRC-32, so the loader can tell a complete, intact download from a damaged one.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace canbridge::sim::firmware {

// CRC-32 as in IEEE 802.3 / zlib (reflected polynomial 0xEDB88320, init and xorout FFFFFFFFh);
// check value of "123456789" is CBF43926h, so `crc32` from any toolchain can build images.
std::uint32_t crc32(std::span<const std::uint8_t> data);

// Image = application bytes, then CRC-32 of them little-endian (4 bytes). The smallest image is
// one application byte.
std::vector<std::uint8_t> make_image(std::span<const std::uint8_t> application);

// The CRC-32 of the application when `image` is well formed (longer than 4 bytes, trailer
// matching), which the loader publishes in 1F56h:01; 0 when it is not (0 is never a valid
// identification because the loader refuses such an image anyway).
struct Verdict {
  bool valid = false;
  std::uint32_t checksum = 0;
};
Verdict verify(std::span<const std::uint8_t> image);

}  // namespace canbridge::sim::firmware
