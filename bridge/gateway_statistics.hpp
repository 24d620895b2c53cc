// The gateway's stats line and RoleStatistics, made from one snapshot of what it counts: text and
// tables only, no process state, so the role gathers the snapshot and tests can build one by hand.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "backbone/message_link.hpp"
#include "bridge/gateway_counters.hpp"
#include "bridge/role_statistics.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

struct GatewayStatsSnapshot {
  std::string name;
  bool connected = false;  // a link to the surface is up
  GatewayCounters counters;
  std::size_t queued = 0;   // frames in the outbox now
  std::size_t unacked = 0;  // reliable messages sent and not acknowledged yet
  std::optional<std::chrono::microseconds> round_trip;  // of the link that is up
  // What the backbone links read and wrote, all links so far (transmitted bytes: in counters).
  backbone::LinkCounters links;
  NodeCounts nodes;
  bool pdop_active = false;  // a module reassembles PDO Packets
  std::uint64_t pdop_dropped_frames = 0;
  std::vector<BusStatistics> buses;  // every module bus, in module order
};

// "gateway NAME: link up, bus->backbone ...": every counter, one line, for the periodic log.
std::string gateway_stats_line(const GatewayStatsSnapshot& snapshot);

// The same counters under the names the stats endpoint and the metrics share with the surface.
RoleStatistics gateway_statistics(const GatewayStatsSnapshot& snapshot);

}  // namespace canbridge::bridge
