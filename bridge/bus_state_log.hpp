// Logs a bus's state changes when they happen: its interface going down and coming back up, and
// the fault-confinement states its error frames announce (bus-off, restarted, ...).
#pragma once

#include <string>

#include "can/bus.hpp"

namespace canbridge::bridge {

// The log line's text for a change, after "<who>: ": "down", "up", "error-warning",
// "error-passive", "bus-off", "restarted (error-active)" (bus-off left), "error-active".
std::string link_change_text(bool up);
std::string state_change_text(can::BusState previous, can::BusState next);

// Installs handlers on `bus` that log each change as "<who>: <text>", e.g. who = "gateway gw1:
// module 2 bus vcan1". They hold only copies, never the role: safe whatever outlives what.
// Logs once now when the interface is down at start.
void log_bus_state_changes(can::Bus& bus, const std::string& who);

}  // namespace canbridge::bridge
