#include "sim/firmware_image.hpp"

#include <array>

#include "canopen/little_endian.hpp"

namespace canbridge::sim::firmware {

namespace {

constexpr std::array<std::uint32_t, 256> make_table() {
  std::array<std::uint32_t, 256> table{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) != 0 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    table[i] = c;
  }
  return table;
}

constexpr auto kTable = make_table();

}  // namespace

std::uint32_t crc32(std::span<const std::uint8_t> data) {
  std::uint32_t c = 0xFFFFFFFFu;
  for (const std::uint8_t b : data) c = kTable[(c ^ b) & 0xFF] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

std::vector<std::uint8_t> make_image(std::span<const std::uint8_t> application) {
  std::vector<std::uint8_t> image(application.begin(), application.end());
  const std::uint32_t crc = crc32(application);
  image.resize(image.size() + 4);
  canopen::store_le(crc, std::span(image).last(4));
  return image;
}

Verdict verify(std::span<const std::uint8_t> image) {
  if (image.size() <= 4) return {};
  const auto application = image.first(image.size() - 4);
  const auto trailer = image.last(4);
  const std::uint32_t stored = canopen::load_le32(trailer);
  const std::uint32_t computed = crc32(application);
  if (stored != computed) return {};
  return {true, computed};
}

}  // namespace canbridge::sim::firmware
