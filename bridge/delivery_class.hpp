// How the backbone treats one message: its delivery class (decided here and nowhere else), the
// bus sender whose order it keeps, and its place in CAN arbitration order, so that a slow link
// favours what the bus itself would favour.
#pragma once

#include <cstdint>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/pdop.hpp"

namespace canbridge::bridge {

// One per message; bridge/delivery_lanes.hpp gives each class its lane (bound, overflow rule,
// order, priority, resent after a cut or not) and docs/backbone.md describes them in one table.
enum class DeliveryClass : std::uint8_t {
  reliable,          // delivered exactly once, in the order its sender sent it
  latest_value,      // heartbeat states: the newest per node kept, never resent
  process_data,      // PDOs, SYNC, TIME: conflated per COB-ID when the module allows it
  ordered_fragment,  // PDO Packet fragments crossing as frames: in bus order, never conflated
  node_event,        // the gateway's node table events (not frames): reliable, ahead of frames
};

// What the classification needs to know beyond the frame itself.
struct DeliveryOptions {
  // The module's `conflate_pdos` (the surface's, for surface frames).
  bool conflate_pdos = false;
  // The PDOs of the frame's node are PDO Packet fragments crossing the backbone as frames
  // (docs/pdop.md section 8, `reassemble: false`).
  bool pdop_fragments = false;
};

// A heartbeat that reports a state (0x701-0x77F, one byte, not the boot-up 00h). It says "alive,
// in this state, now": replaying heartbeats queued during a link cut would show a master nodes
// that may have died meanwhile, so only the newest one per node is kept and it is never resent.
inline bool is_heartbeat_state(const can::Frame& frame) {
  return !frame.is_extended() && !frame.is_remote() && frame.id > 0x700 && frame.id <= 0x77F &&
         frame.len == 1 && frame.data[0] != 0x00;
}

// Process data: plain PDOs (CiA 301 function codes 0x180-0x57F), SYNC (0x080), TIME (0x100) and
// heartbeat states. Everything else (NMT, boot-ups, EMCY, SDO, node guarding, LSS, extended and
// remote frames) is reliable: delivered exactly once, in order, across link cuts.
inline DeliveryClass classify(const can::Frame& frame, const DeliveryOptions& options) {
  if (frame.is_extended() || frame.is_remote()) return DeliveryClass::reliable;
  if (is_heartbeat_state(frame)) return DeliveryClass::latest_value;
  const std::uint8_t function_code = canopen::pdop::decode(frame.id).function_code;
  if (options.pdop_fragments &&
      (canopen::pdop::tpdo_number(function_code) || canopen::pdop::rpdo_number(function_code))) {
    // Its four t/c variants are different COB-IDs and fragment k and k + 2 share one, so neither
    // arbitration order nor conflation may apply (docs/pdop.md section 8).
    return DeliveryClass::ordered_fragment;
  }
  if (frame.id == 0x080 || frame.id == 0x100 || (frame.id >= 0x180 && frame.id <= 0x57F)) {
    return DeliveryClass::process_data;
  }
  return DeliveryClass::reliable;
}

// One master sends all of these, so they share one sender whatever their COB-ID.
inline constexpr canopen::NodeId kMasterSender = 0;

// Whose frame this is on its bus, for keeping each sender's frames in the order it sent them:
// the node id for what a node sends under the CiA 301 predefined connection set (EMCY 0x81-0xFF,
// TPDOs, SDO responses 0x581-0x5FF, heartbeats and boot-ups 0x701-0x77F), kMasterSender for what
// a master sends (NMT, SYNC, TIME, SDO requests, RPDOs, LSS, remote requests) and for anything
// else (extended frames, unassigned COB-IDs): the master's NMT after its SDO request stays after
// it.
inline canopen::NodeId bus_sender(const can::Frame& frame) {
  if (frame.is_extended() || frame.is_remote()) return kMasterSender;
  const auto address = canopen::split_predefined(frame.id);
  if (!address) return kMasterSender;
  switch (address->function_base) {
    case canopen::cob::emcy:
    case canopen::cob::tpdo1:
    case canopen::cob::tpdo2:
    case canopen::cob::tpdo3:
    case canopen::cob::tpdo4:
    case canopen::cob::sdo_tx:
    case canopen::cob::heartbeat:
      return address->node;
    default:
      return kMasterSender;
  }
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
