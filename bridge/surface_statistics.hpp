// The surface's stats line and RoleStatistics, made from one snapshot of what it counts: text and
// tables only, no process state, so the role gathers the snapshot and tests can build one by hand.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include "backbone/message_link.hpp"
#include "bridge/role_statistics.hpp"
#include "bridge/surface_counters.hpp"

namespace canbridge::bridge {

struct SurfaceStatsSnapshot {
  std::string name;
  SurfaceCounters counters;
  std::size_t gateways_up = 0;          // bound and ready now
  std::size_t gateways_configured = 0;  // in the config
  std::size_t gateways_known = 0;       // with an id in the gateway table
  BusStatistics bus;                    // the surface bus
  // What the backbone links read and wrote, all links so far, transmitted bytes included.
  backbone::LinkCounters links;
  std::size_t unacked = 0;  // reliable messages sent and not acknowledged yet, all gateways
  std::optional<std::chrono::microseconds> round_trip;  // the slowest gateway whose link is up
  NodeSummary nodes;
};

// "surface NAME: 1/1 gateway(s) up, bus->backbone ...": every counter, one line, for the log.
std::string surface_stats_line(const SurfaceStatsSnapshot& snapshot);

// The same counters under the names the stats endpoint and the metrics share with the gateway.
RoleStatistics surface_statistics(const SurfaceStatsSnapshot& snapshot);

}  // namespace canbridge::bridge
