// What a gateway's node event says to an operator watching the surface: one line per event
// (boot-ups, losses, renames are rare), with the level it deserves. Pure: no logging here.
#pragma once

#include <string>
#include <string_view>

#include "canbridge.pb.h"

namespace canbridge::bridge {

struct NodeEventLine {
  enum class Level { debug, info, warning };
  Level level = Level::info;
  std::string text;  // without the "surface: " prefix
};

// The line for `event`, sent by the gateway named `gateway`. An event of a kind this version
// does not know gets a debug line.
NodeEventLine node_event_line(std::string_view gateway, const v1::NodeEvent& event);

}  // namespace canbridge::bridge
