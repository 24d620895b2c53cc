// The three ways a RoleStatistics snapshot is shown: the short periodic log line, the full JSON
// document of `canbridge stats`, and the Prometheus text exposition format (version 0.0.4).
#pragma once

#include <string>

#include "bridge/role_statistics.hpp"

namespace canbridge::bridge {

// "NAME" for a bus's state: "down" while its interface is lost, else its fault-confinement
// state ("error-active", "error-warning", "error-passive", "bus-off").
std::string bus_state_name(const BusStatistics& bus);

// One short line for the log: link and round trip, the busiest buses' rates (and every bus that
// is not down-free and error-active), backbone throughput, drops with their largest reasons,
// and the node summary.
std::string statistics_line(const RoleStatistics& stats, const RoleRates& rates);

// Every counter, gauge and rate as one JSON object on one line (no line breaks inside).
std::string statistics_json(const RoleStatistics& stats, const RoleRates& rates);

// Counters as `canbridge_..._total`, states as gauges; labels module, bus, direction, reason.
std::string statistics_prometheus(const RoleStatistics& stats);

// `text` as a JSON string literal, quotes included (control characters as \u00XX).
std::string json_string(const std::string& text);

}  // namespace canbridge::bridge
