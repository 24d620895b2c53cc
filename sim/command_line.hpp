// canbridge-sim's command line, parsed (CLI11) into the options of a run, or text to print and
// an exit status (help, version, usage errors).
#pragma once

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "logging/log_setup.hpp"

namespace canbridge::sim {

struct SimOptions {
  std::string rig_path;
  std::set<std::string> buses;                    // --bus (empty: every bus)
  std::map<std::string, std::string> interfaces;  // --interface BUS=IFACE
  bool all_virtual = false;                       // --virtual
  unsigned stats_seconds = 10;                    // --stats-seconds (0: never)
  std::optional<std::string> log_level;           // -v, -vv, --log-level (default info)
  logging::LogFormat log_format = logging::LogFormat::automatic;
};

struct SimCommandLine {
  std::optional<SimOptions> options;  // set when the program should run
  int exit_status = 0;                // otherwise: 0 after help or version, 2 after an error
  std::string output;                 // for stdout (help, version)
  std::string error;                  // for stderr
};

// `args`: argv without the program; `version` is what --version prints after the name.
SimCommandLine parse_sim_command_line(const std::vector<std::string>& args,
                                      const std::string& version);

}  // namespace canbridge::sim
