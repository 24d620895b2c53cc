// The parts of the roles' stats lines that both roles share: a bus's counters, the session's and
// the serial framing's, each counter under its own label, so no counted loss goes unprinted.
#pragma once

#include <string>

#include "backbone/serial_framing.hpp"
#include "backbone/session.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

// "NAME rx N tx N kernel-drops N ... STATE": every BusCounters field.
std::string bus_counters_text(const std::string& name, const can::BusCounters& c);
// "session links N ... unreliable sent N delivered N lost-on-line N": the SessionCounters that
// the roles' lines do not print elsewhere.
std::string session_counters_text(const backbone::SessionCounters& c);
// "framing: frames N crc-errors N ...": every DeframerCounters field.
std::string framing_counters_text(const backbone::DeframerCounters& c);

}  // namespace canbridge::bridge
