#include "backbone/crc32c.hpp"

#include <array>
#include <cstddef>

#include "backbone/little_endian.hpp"

namespace canbridge::backbone {

namespace {

constexpr std::uint32_t kReflectedPolynomial = 0x82F63B78u;

// Slicing-by-8: table k maps a byte to its CRC contribution when k more bytes follow it, so the
// main loop folds eight input bytes per step with eight independent lookups instead of eight
// dependent ones.
using SlicingTables = std::array<std::array<std::uint32_t, 256>, 8>;

constexpr SlicingTables make_slicing_tables() {
  SlicingTables tables{};
  for (std::uint32_t byte = 0; byte < 256; ++byte) {
    std::uint32_t crc = byte;
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ ((crc & 1u) ? kReflectedPolynomial : 0u);
    tables[0][byte] = crc;
  }
  for (std::size_t k = 1; k < tables.size(); ++k) {
    for (std::size_t byte = 0; byte < 256; ++byte) {
      const std::uint32_t previous = tables[k - 1][byte];
      tables[k][byte] = (previous >> 8) ^ tables[0][previous & 0xFFu];
    }
  }
  return tables;
}

constexpr SlicingTables kTables = make_slicing_tables();

// The byte-at-a-time step, also the definition the slicing tables are derived from.
static_assert(kTables[0][1] == 0xF26B8303u, "CRC-32C table does not match the polynomial");

}  // namespace

std::uint32_t crc32c(std::span<const std::uint8_t> data, std::uint32_t crc) noexcept {
  std::uint32_t state = ~crc;
  const std::uint8_t* p = data.data();
  std::size_t n = data.size();
  while (n >= 8) {
    const std::uint32_t low = state ^ load_le32(p);
    const std::uint32_t high = load_le32(p + 4);
    state = kTables[7][low & 0xFFu] ^ kTables[6][(low >> 8) & 0xFFu] ^
            kTables[5][(low >> 16) & 0xFFu] ^ kTables[4][low >> 24] ^ kTables[3][high & 0xFFu] ^
            kTables[2][(high >> 8) & 0xFFu] ^ kTables[1][(high >> 16) & 0xFFu] ^
            kTables[0][high >> 24];
    p += 8;
    n -= 8;
  }
  for (; n != 0; --n, ++p) state = kTables[0][(state ^ *p) & 0xFFu] ^ (state >> 8);
  return ~state;
}

}  // namespace canbridge::backbone
