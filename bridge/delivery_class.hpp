// How the backbone treats one CAN frame: reliable or conflatable process data, and its place in
// CAN arbitration order, so that a slow link favours what the bus itself would favour.
#pragma once

#include <cstdint>

#include "can/frame.hpp"

namespace canbridge::bridge {

// A heartbeat that reports a state (0x701-0x77F, one byte, not the boot-up 00h). It says "alive,
// in this state, now": replaying heartbeats queued during a link cut would show a master nodes
// that may have died meanwhile, so only the newest one per node is kept and it is never resent.
inline bool is_heartbeat_state(const can::Frame& frame) {
  return !frame.is_extended() && !frame.is_remote() && frame.id > 0x700 && frame.id <= 0x77F &&
         frame.len == 1 && frame.data[0] != 0x00;
}

// Process data: plain PDOs (CiA 301 function codes 0x180-0x57F), SYNC (0x080), TIME (0x100) and
// heartbeat states. Only the latest value matters, so under backlog a newer frame may replace an
// older one of the same COB-ID, and a lost one is not resent. Everything else (NMT, boot-ups,
// EMCY, SDO, node guarding, LSS, extended and remote frames) is reliable: delivered exactly once,
// in order, across link cuts.
inline bool is_process_data(const can::Frame& frame) {
  if (frame.is_extended() || frame.is_remote()) return false;
  return frame.id == 0x080 || frame.id == 0x100 || (frame.id >= 0x180 && frame.id <= 0x57F) ||
         is_heartbeat_state(frame);
}

// Arbitration order as 30 bits: the 11-bit base identifier first, then a standard frame before
// an extended one with the same base (its IDE bit is dominant), then the 18-bit extension.
inline std::uint32_t arbitration_priority(const can::Frame& frame) {
  if (!frame.is_extended()) return frame.id << 19;
  return ((frame.id >> 18) << 19) | (1u << 18) | (frame.id & 0x3FFFFu);
}

// Frames with the same key replace each other under conflation: same module, same identifier.
inline std::uint64_t conflation_key(std::uint32_t module_id, const can::Frame& frame) {
  return (std::uint64_t{module_id} << 32) | (frame.is_extended() ? 0x80000000u : 0u) | frame.id;
}

}  // namespace canbridge::bridge
