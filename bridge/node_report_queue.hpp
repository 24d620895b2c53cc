// The gateway's reports of its node table to the surface: node events and node table snapshots,
// encoded as NodeEvents payloads and queued until the link takes them, bounded so that a link
// down for hours cannot grow the queue without end. Pure: events and the table in, payloads out.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <span>
#include <string>
#include <vector>

#include "canbridge.pb.h"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

class NodeReportQueue {
 public:
  struct Counters {
    std::uint64_t events = 0;          // events queued, snapshots' included
    std::uint64_t events_dropped = 0;  // of those, dropped by the bound before they were sent
  };

  // `map` and `table` are the gateway's and must outlive this; `module_ids` in the map's order.
  // At most `max_payloads` payloads of events wait (at least 1); a snapshot's payloads, one per
  // module, may come on top.
  NodeReportQueue(const NodeMap& map, const NodeTable& table, std::vector<ModuleId> module_ids,
                  std::size_t max_payloads);

  // One payload with `events` (their renames already followed in the map) and, if not empty,
  // the gateway's new claims (a serialized GatewayClaims: a node moved in the live map). False
  // if the oldest payload of events had to be dropped to make room (counted).
  bool queue_events(std::span<const NodeEvent> events, const std::string& claims);

  struct Snapshot {
    std::size_t nodes = 0;  // nodes reported
    std::size_t lost = 0;   // of those, lost
    bool dropped = false;   // events had to be dropped to make room
  };
  // Everything the table knows, for a surface process that has not heard from this gateway:
  // each node as discovered in its present state, then lost if it is. Replaces a snapshot still
  // queued (it was for a surface process that never got it).
  Snapshot queue_snapshot();

  // The oldest payload, to be sent (moved from) and then popped; nullptr when none waits.
  std::string* front() { return queue_.empty() ? nullptr : &queue_.front().payload; }
  void pop() { queue_.pop_front(); }
  std::size_t size() const { return queue_.size(); }
  const Counters& counters() const { return counters_; }

 private:
  struct Queued {
    std::string payload;  // a serialized Payload carrying NodeEvents
    std::size_t events;
    // Part of a node table snapshot: never dropped by the bound, since no later event repeats
    // the state of a node that stays in it.
    bool snapshot = false;
  };
  // The fields every node event carries: which node (module, local and surface id) and how it is.
  void describe(std::size_t m, NodeId local, NmtState state, std::uint32_t boot_count,
                v1::NodeEvent& out) const;
  // Drops the oldest payload of events if the queue is full; true if it did.
  bool make_room();

  const NodeMap* map_;
  const NodeTable* table_;
  std::vector<ModuleId> module_ids_;
  std::size_t max_payloads_;
  std::deque<Queued> queue_;  // oldest first
  Counters counters_;
};

}  // namespace canbridge::bridge
