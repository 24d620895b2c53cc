#include "logging/command_line_common.hpp"

#include <CLI/CLI.hpp>

namespace canbridge::logging {

std::optional<std::string> LogArguments::log_level() const {
  if (!level.empty()) return level;
  if (verbosity == 1) return "debug";
  if (verbosity > 1) return "trace";
  return std::nullopt;
}

LogFormat LogArguments::log_format() const {
  return parse_log_format(format).value_or(LogFormat::automatic);
}

void add_log_options(CLI::App& app, LogArguments& log, std::string_view note) {
  auto* verbose = app.add_flag("-v,--verbose", log.verbosity,
                               "more log: -v debug, -vv trace" + std::string(note));
  app.add_option("--log-level", log.level, "trace|debug|info|warn|error|off" + std::string(note))
      ->type_name("LEVEL")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}))
      ->excludes(verbose);
  app.add_option("--log-format", log.format,
                 "auto|text|journal: journal = sd-daemon priority prefixes, no timestamps; auto "
                 "picks journal when stderr is the journal (default auto)")
      ->type_name("FORMAT")
      ->check(CLI::IsMember({"auto", "text", "journal"}));
}

std::string usage_message(const CLI::App& app, const CLI::ParseError& error) {
  std::string message = error.what();
  if (dynamic_cast<const CLI::ExtrasError*>(&error) != nullptr) {
    // CLI11 lists them backwards (it parses a reversed vector): name them as given.
    message = "unexpected argument(s):";
    for (const std::string& extra : app.remaining()) message += " " + extra;
  } else if (dynamic_cast<const CLI::ConversionError*>(&error) != nullptr) {
    message += ": expected a number";
  } else if (dynamic_cast<const CLI::ArgumentMismatch*>(&error) != nullptr) {
    // CLI11 words both cases as counts ("--config: At Most 1 required but received 2",
    // "--config: 1 required FILE missing"): say which one it is.
    const std::string name = message.substr(0, message.find(':'));
    const std::string_view received = " but received ";
    const std::string_view required = " required ";
    const std::string_view missing = " missing";
    const auto at_most = message.find("At Most ");
    const auto count = message.find(received);
    const auto type = message.find(required);
    if (at_most != std::string::npos && count != std::string::npos) {
      message =
          name + ": given " + message.substr(count + received.size()) + " times, expected once";
    } else if (type != std::string::npos && message.ends_with(missing)) {
      // The value's type name, unless it is CLI11's anonymous TEXT.
      const std::string value = message.substr(
          type + required.size(), message.size() - missing.size() - type - required.size());
      message = name + " needs a value" + (value == "TEXT" ? "" : " (" + value + ")");
    } else {
      message += " (it needs a value)";
    }
  }
  return message;
}

}  // namespace canbridge::logging
