// Fills the parts of a role's statistics that the gateway and the surface count under the same
// names (session, outbox, link and bus-write counters), so both roles report them alike.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "backbone/message_link.hpp"
#include "bridge/bus_write_queue.hpp"
#include "bridge/role_statistics.hpp"

namespace canbridge::bridge {

// RoleCounters: GatewayCounters or SurfaceCounters (session, outbox, frames_received).
template <class RoleCounters>
void copy_stream_counters(const RoleCounters& c, BackboneStatistics& b) {
  b.links = c.session.links;
  b.dead_links = c.session.dead_links;
  b.frames_sent = c.outbox.frames_sent;
  b.frames_received = c.frames_received;
  b.batches_sent = c.outbox.batches_sent;
  b.reliable_sent = c.session.reliable_sent;
  b.reliable_resent = c.session.reliable_resent;
  b.resend_requests = c.session.resend_requests;
}

// What a link reads and writes; transmitted bytes are left to the caller (the gateway counts
// them across its links already).
inline void add_link_reads_and_writes(const backbone::LinkCounters& now, BackboneStatistics& b) {
  b.rx_bytes += now.rx_bytes;
  b.rx_messages += now.rx_messages;
  b.tx_writes += now.tx_writes;
}

// The same into a total over links (a role's statistics snapshot).
inline void add_link_reads_and_writes(const backbone::LinkCounters& now,
                                      backbone::LinkCounters& total) {
  total.rx_bytes += now.rx_bytes;
  total.rx_messages += now.rx_messages;
  total.tx_writes += now.tx_writes;
}

// Bus-write drops by reason, then the refusals no reason accounts for.
template <class RoleCounters>
void add_bus_write_drops(const RoleCounters& c, std::vector<DropCount>& drops) {
  std::uint64_t by_reason = 0;
  for (std::size_t r = 0; r < BusWriteQueue::kDropReasons; ++r) {
    drops.push_back({std::string("bus-write-") + to_string(static_cast<BusWriteQueue::Drop>(r)),
                     c.bus_drops[r]});
    by_reason += c.bus_drops[r];
  }
  drops.push_back({"bus-write-refused", c.bus_refused > by_reason ? c.bus_refused - by_reason : 0});
}

}  // namespace canbridge::bridge
