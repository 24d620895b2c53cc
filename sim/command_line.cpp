#include "sim/command_line.hpp"

#include <CLI/CLI.hpp>

#include "logging/command_line_common.hpp"

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
  logging::LogArguments log;
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
  logging::add_log_options(app, log, " (default info)");

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
    const std::string message = logging::usage_message(app, e);
    result.exit_status = 2;
    result.error = "canbridge-sim: " + message + "\nrun 'canbridge-sim --help' for the usage\n";
    return result;
  }
  options.buses.insert(buses.begin(), buses.end());
  for (const std::string& pair : interfaces) {
    const auto eq = pair.find('=');
    options.interfaces[pair.substr(0, eq)] = pair.substr(eq + 1);
  }
  options.log_level = log.log_level();
  options.log_format = log.log_format();
  result.options = std::move(options);
  return result;
}

}  // namespace canbridge::sim
