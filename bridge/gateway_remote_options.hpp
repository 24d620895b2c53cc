// Options of the services a gateway runs for the surface on its module buses (SDO client,
// firmware download, NMT, LSS; docs/remote-access.md).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>

namespace canbridge::bridge {

struct GatewayRemoteOptions {
  std::chrono::milliseconds sdo_timeout{1000};  // when the request gives none
  // Firmware download: block size, the wait for a loader that erases flash before it answers
  // (CiA 302 allows seconds), and the wait for each boot-up (loader, then application).
  std::uint8_t flash_block_size = 127;
  std::chrono::milliseconds flash_answer_timeout{std::chrono::seconds(20)};
  std::chrono::milliseconds boot_timeout{std::chrono::seconds(10)};
  // Requests waiting per node (beyond: refused with 0x08000021 at once).
  std::size_t max_queued_per_node = 64;
};

}  // namespace canbridge::bridge
