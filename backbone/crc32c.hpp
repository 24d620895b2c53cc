// CRC-32C (Castagnoli), the checksum that lets a serial-line receiver reject corrupted frames.
#pragma once

#include <cstdint>
#include <span>

namespace canbridge::backbone {

// CRC-32C of `data`: reflected polynomial 0x82F63B78, initial value and final xor 0xFFFFFFFF
// (the iSCSI / ext4 / SCTP variant; crc32c("123456789") == 0xE3069283).
// Chainable, so a message that arrives in pieces needs no copy: pass the CRC of what came before
// as `crc`, i.e. crc32c(b, crc32c(a)) == crc32c(a followed by b); 0 starts a new message.
std::uint32_t crc32c(std::span<const std::uint8_t> data, std::uint32_t crc = 0) noexcept;

}  // namespace canbridge::backbone
