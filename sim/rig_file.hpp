// Reads a rig file (YAML: the buses of a simulation and the CANopen nodes on each) into a RigSpec,
// validating it completely so that a node core never sees an option it cannot honour.
//
// Schema and rules: config/rigs/README.md; samples: config/rigs/*.yaml.
#pragma once

#include <string>
#include <string_view>

#include "sim/node_spec.hpp"
#include "yaml/config_error.hpp"

namespace canbridge::sim {

// Startup code. Throws config::ConfigError listing every problem of the file (file, 1-based line,
// dotted field such as buses[1].nodes[0].node_id), or naming the file when it cannot be read.
RigSpec load_rig(const std::string& path);

// Same, from text already in memory; `file` names it in problems.
RigSpec parse_rig(std::string_view yaml, const std::string& file);

}  // namespace canbridge::sim
