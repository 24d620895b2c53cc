// What a config reload (SIGHUP) changes in a running role: the settings that apply at once (the
// log level, the statistics interval) and the sections whose change needs a restart. Pure: the
// signal, the file and the logging live in reload_on_hangup.hpp.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "config/options.hpp"

namespace canbridge::bridge {

// The reloadable settings as the process runs them.
struct RunningLogSettings {
  std::string level;  // as applied (the command line's when it fixed it)
  std::chrono::seconds stats_interval{0};
  bool level_fixed = false;  // -v or --log-level: the file's log.level does not apply
};

struct ReloadPlan {
  std::optional<std::string> level;                    // a new level to apply
  std::optional<std::chrono::seconds> stats_interval;  // a new interval to apply
  std::optional<std::string> ignored_level;   // the file's new level, ignored (command line fixed)
  std::vector<std::string> restart_sections;  // changed top-level sections other than log
};

// The top-level sections (keys) of two config texts whose content differs, in the order they
// appear (the started file's first): comments, layout and key order inside a section do not
// count. A text that is not YAML counts as entirely changed.
std::vector<std::string> changed_sections(std::string_view started, std::string_view reloaded);

// What to do with a reloaded file's log options and its changed sections.
ReloadPlan plan_reload(const RunningLogSettings& running, const config::LogOptions& reloaded,
                       const std::vector<std::string>& changed);

// The log line saying what the reload applied, e.g. "config reloaded from F: log.level debug
// (was info), log.stats_interval_s 5 (was 10)".
std::string applied_line(const ReloadPlan& plan, const RunningLogSettings& running,
                         const std::string& file);
// The log line naming what needs a restart, e.g. "config reload: backbone, modules changed:
// restart to apply".
std::string restart_line(const ReloadPlan& plan);

}  // namespace canbridge::bridge
