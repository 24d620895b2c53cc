// CRC-16 of CiA 301 SDO block transfers (CRC-16/XMODEM: poly 0x1021, init 0, no reflection, no
// final xor), computed incrementally so a transfer can checksum its data as it goes.
#pragma once

#include <cstdint>
#include <span>

namespace canbridge::canopen {

// CRC of `data` continuing from `crc` (0 to start); crc16_xmodem("123456789") == 0x31C3.
std::uint16_t crc16_xmodem(std::span<const std::uint8_t> data, std::uint16_t crc = 0);

}  // namespace canbridge::canopen
