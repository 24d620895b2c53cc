// SIGHUP for a role process: re-reads the config file it started with and applies what can change
// without a restart (log.level, log.stats_interval_s), logging what it applied and which other
// changes need a restart; an invalid file is reported and the running settings stay.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/signal_set.hpp>
#include <chrono>
#include <functional>
#include <string>
#include <string_view>

#include "app/reload_plan.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// Where a role's reloadable settings come from: the file it started with, and whether the
// command line fixed the log level (-v, --log-level; then the file's log.level never applies).
struct HangupReloadSource {
  std::string config_path;  // empty: SIGHUP is ignored (nothing to re-read)
  bool log_level_fixed = false;
};

class ReloadOnHangup {
 public:
  // The role's loader on text (parse_gateway or parse_surface), returning the log options;
  // throws config::ConfigError for an invalid file.
  using ParseLog =
      std::function<config::LogOptions(std::string_view text, const std::string& file)>;

  // `running`: the log options in force (with the command line's level when it fixed it).
  ReloadOnHangup(boost::asio::any_io_executor executor, HangupReloadSource source,
                 const config::LogOptions& running, ParseLog parse,
                 std::function<void(std::chrono::seconds)> set_stats_interval);
  // Stops listening (for the ordered shutdown); SIGHUP stays caught, so it cannot kill the drain.
  void stop() { signals_.cancel(); }

 private:
  void wait();
  void reload();

  boost::asio::signal_set signals_;
  HangupReloadSource source_;
  // The file as the process started with it: what the sections are compared against, as the
  // running process still runs them until a restart.
  std::string started_text_;
  RunningLogSettings running_;
  ParseLog parse_;
  std::function<void(std::chrono::seconds)> set_stats_interval_;
};

}  // namespace canbridge::bridge
