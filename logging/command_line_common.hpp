// The parts of the command-line grammar every canbridge executable shares (canbridge,
// canbridge-sim, canbridge-link-emulator): the log options and how a CLI11 parse error is said.
// It lives beside the log setup because logging/ is the one leaf library all three link.
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "logging/log_setup.hpp"

namespace CLI {
class App;
class ParseError;
}  // namespace CLI

namespace canbridge::logging {

// What -v/--verbose, --log-level and --log-format set while CLI11 parses.
struct LogArguments {
  int verbosity = 0;
  std::string level;
  std::string format = "auto";

  // --log-level, else -v (debug) or -vv (trace), else nullopt (the configured level stays).
  std::optional<std::string> log_level() const;
  // The --log-format value (checked by the option, so always one of the formats).
  LogFormat log_format() const;
};

// Adds -v/--verbose (counted), --log-level (excludes -v) and --log-format to `app`. `note` ends
// the help of -v and --log-level, e.g. " (overrides the file's log.level)".
void add_log_options(CLI::App& app, LogArguments& log, std::string_view note);

// The message of a parse error of `app`, saying what was expected where CLI11 does not:
// unexpected arguments in the order given (the parsers hand CLI11 a reversed vector), "expected a
// number" after a failed conversion, "--config needs a value (FILE)" for an option without one,
// and "--config: given 2 times, expected once" for a repeated single-value option.
std::string usage_message(const CLI::App& app, const CLI::ParseError& error);

}  // namespace canbridge::logging
