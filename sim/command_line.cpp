#include "sim/command_line.hpp"

#include <CLI/CLI.hpp>

namespace canbridge::sim {

SimCommandLine parse_sim_command_line(const std::vector<std::string>& args,
                                      const std::string& version) {
  CLI::App app{
      "canbridge-sim: runs the simulated CANopen nodes of a rig file (see "
      "config/rigs/README.md)",
      "canbridge-sim"};
  app.set_version_flag("--version", "canbridge-sim " + version, "print the version and exit");
  app.footer(
      "Prints \"canbridge-sim: ready ...\" once every node has booted; stops on SIGINT/SIGTERM.");
  SimOptions options;
  std::vector<std::string> buses;
  std::vector<std::string> interfaces;
  int verbosity = 0;
  std::string level;
  std::string format = "auto";
  app.add_option("RIG", options.rig_path, "the rig file (YAML)")->required()->type_name("FILE");
  app.add_option("--bus", buses, "run only this bus (repeatable; default: every bus)")
      ->type_name("NAME")
      ->expected(1)  // one value per --bus: the rig file may follow
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  app.add_option("--interface", interfaces,
                 "put bus BUS on SocketCAN interface IFACE instead of the file's (repeatable)")
      ->type_name("BUS=IFACE")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll)
      ->check(
          [](const std::string& value) -> std::string {
            const auto eq = value.find('=');
            if (eq == std::string::npos || eq == 0 || eq + 1 == value.size()) {
              return "'" + value + "' is not BUS=IFACE";
            }
            return {};
          },
          "");
  app.add_flag("--virtual", options.all_virtual,
               "every bus on an in-process virtual bus (no SocketCAN needed)");
  app.add_option("--stats-seconds", options.stats_seconds,
                 "log bus counters every N seconds (default 10, 0 = never)")
      ->type_name("N");
  auto* verbose = app.add_flag("-v,--verbose", verbosity, "more log: -v debug, -vv trace");
  app.add_option("--log-level", level, "trace|debug|info|warn|error|off (default info)")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}))
      ->excludes(verbose);
  app.add_option("--log-format", format,
                 "auto|text|journal: journal = sd-daemon priority prefixes, no timestamps; auto "
                 "picks journal when stderr is the journal (default auto)")
      ->check(CLI::IsMember({"auto", "text", "journal"}));

  SimCommandLine result;
  try {
    app.parse(std::vector<std::string>(args.rbegin(), args.rend()));
  } catch (const CLI::CallForHelp&) {
    result.output = app.help();
    return result;
  } catch (const CLI::CallForVersion& e) {
    result.output = std::string(e.what()) + "\n";
    return result;
  } catch (const CLI::ParseError& e) {
    std::string message = e.what();
    if (dynamic_cast<const CLI::ExtrasError*>(&e) != nullptr) {
      // CLI11 lists them backwards (it parses a reversed vector): name them as given.
      message = "unexpected argument(s):";
      for (const std::string& extra : app.remaining()) message += " " + extra;
    }
    if (dynamic_cast<const CLI::ConversionError*>(&e) != nullptr) message += ": expected a number";
    result.exit_status = 2;
    result.error = "canbridge-sim: " + message + "\nrun 'canbridge-sim --help' for the usage\n";
    return result;
  }
  options.buses.insert(buses.begin(), buses.end());
  for (const std::string& pair : interfaces) {
    const auto eq = pair.find('=');
    options.interfaces[pair.substr(0, eq)] = pair.substr(eq + 1);
  }
  if (!level.empty()) {
    options.log_level = level;
  } else if (verbosity > 0) {
    options.log_level = verbosity == 1 ? "debug" : "trace";
  }
  options.log_format = *logging::parse_log_format(format);  // checked by IsMember
  result.options = std::move(options);
  return result;
}

}  // namespace canbridge::sim
