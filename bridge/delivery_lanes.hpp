// The lanes that carry each delivery class across the backbone, in one table: bound, overflow
// rule, conflation, what one FIFO holds, priority, and whether the lane is resent after a cut.
#pragma once

#include <array>
#include <cstddef>
#include <string_view>

#include "backbone/priority_scheduler.hpp"
#include "bridge/delivery_class.hpp"

namespace canbridge::bridge {

// The lanes' bounds, in frames (node events: in payloads). The roles set the reliable and the
// process bound from `queue_reliable_frames` and `queue_process_frames`; a latest value per
// node and COB-ID needs far fewer entries, and packets crossing as frames are rare.
struct LaneBounds {
  std::size_t max_reliable_frames = 1u << 16;
  std::size_t max_latest_values = 1u << 12;
  std::size_t max_process_frames = 1u << 14;
  std::size_t max_fragment_frames = 1u << 14;
  std::size_t max_node_event_payloads = 1024;
};

// What one FIFO of a lane holds: frames of one FIFO never overtake each other, while the heads of
// different FIFOs compete by priority.
enum class FifoPer {
  sender,  // one node, or the master (bus_sender): a node's boot-up stays ahead of its EMCY
  cob_id,  // one COB-ID of one module
  packet,  // one PDO Packet stream (a node's TPDO/RPDO number): fragments in bus order
  role,    // one queue for the whole role
};

enum class Conflation {
  never,
  always,         // a newer value replaces the queued one of the same COB-ID in place
  module_option,  // as `always` when the module's `conflate_pdos` allows it, else never
};

enum class Rank {
  arbitration,      // by CAN arbitration order of the FIFO's head frame, as the bus would
  ahead_of_frames,  // before any frame lane
};

struct Lane {
  DeliveryClass delivery;
  std::string_view name;  // in stats lines
  std::size_t LaneBounds::*bound;
  backbone::Overflow overflow;
  Conflation conflation;
  FifoPer fifo;
  Rank rank;
  bool reliable;  // sequenced, acknowledged and resent after a link cut
};

// Indexed by DeliveryClass. Reliable frames are refused (and counted, and warned about) rather
// than dropped: the caller knows they were not sent. Values are dropped oldest first: the newest
// value is the one a master wants. A fragment is refused: dropping an older one would break a
// packet already under way as well.
inline constexpr std::array<Lane, 5> kLanes = {{
    {DeliveryClass::reliable, "reliable", &LaneBounds::max_reliable_frames,
     backbone::Overflow::refuse, Conflation::never, FifoPer::sender, Rank::arbitration, true},
    {DeliveryClass::latest_value, "latest-value", &LaneBounds::max_latest_values,
     backbone::Overflow::drop_oldest, Conflation::always, FifoPer::cob_id, Rank::arbitration,
     false},
    {DeliveryClass::process_data, "process", &LaneBounds::max_process_frames,
     backbone::Overflow::drop_oldest, Conflation::module_option, FifoPer::cob_id, Rank::arbitration,
     false},
    {DeliveryClass::ordered_fragment, "fragment", &LaneBounds::max_fragment_frames,
     backbone::Overflow::refuse, Conflation::never, FifoPer::packet, Rank::arbitration, false},
    {DeliveryClass::node_event, "node-event", &LaneBounds::max_node_event_payloads,
     backbone::Overflow::drop_oldest, Conflation::never, FifoPer::role, Rank::ahead_of_frames,
     true},
}};

constexpr const Lane& lane_of(DeliveryClass delivery) {
  return kLanes[static_cast<std::size_t>(delivery)];
}

// The lanes FrameOutbox carries (the first ones of kLanes): every class but node events, which
// are payloads the gateway queues itself.
inline constexpr std::size_t kFrameLanes = 4;

constexpr bool lanes_in_class_order() {
  for (std::size_t i = 0; i < kLanes.size(); ++i) {
    if (static_cast<std::size_t>(kLanes[i].delivery) != i) return false;
  }
  for (std::size_t i = 0; i < kLanes.size(); ++i) {
    if ((kLanes[i].rank == Rank::arbitration) != (i < kFrameLanes)) return false;
  }
  return true;
}
static_assert(lanes_in_class_order(), "kLanes is indexed by DeliveryClass, frame lanes first");

}  // namespace canbridge::bridge
