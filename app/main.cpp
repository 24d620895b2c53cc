// canbridge: the command-line entry point of every role (gateway, surface, demo) and of the
// operator subcommands; the grammar is app/command_line.hpp.
#include <unistd.h>

#include <algorithm>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "app/cli_main.hpp"
#include "app/command_line.hpp"
#include "app/config_check.hpp"
#include "app/demo.hpp"
#include "app/run_roles.hpp"
#include "config/loader.hpp"
#include "logging/log_setup.hpp"

namespace {

using canbridge::bridge::Command;
using canbridge::bridge::CommandLine;

// An error main writes itself, not through the logger: in the journal format every line has the
// error priority, as the logger's own error lines do (a config error is several lines).
void print_error(canbridge::logging::LogFormat format, const std::string& text) {
  std::cerr << canbridge::logging::prefix_lines(canbridge::logging::resolve(format),
                                                spdlog::level::err, text);
}

int usage_error(const CommandLine& command_line, const std::string& message) {
  print_error(command_line.log_format, "canbridge: " + message);
  return 2;
}

// The gateway or surface of a parsed command line: loads its file, lets the command line
// override what it may, and runs the role until a signal.
int run_role(const CommandLine& command_line) {
  if (const auto missing = canbridge::bridge::missing_default_config(command_line)) {
    return usage_error(command_line, *missing);
  }
  const canbridge::bridge::HangupReloadSource reload{command_line.config_path,
                                                     command_line.log_level.has_value()};
  if (command_line.command == Command::surface) {
    auto options = canbridge::config::load_surface(command_line.config_path);
    if (command_line.log_level) options.log.level = *command_line.log_level;
    return canbridge::bridge::run_surface(options, reload);
  }
  auto options = canbridge::config::load_gateway(command_line.config_path);
  if (command_line.log_level) options.log.level = *command_line.log_level;
  if (command_line.lss_module) {
    // A commissioning session picks the bus LSS reaches without editing the file.
    const std::uint32_t id = *command_line.lss_module;
    const bool served = std::any_of(options.modules.begin(), options.modules.end(),
                                    [&](const auto& m) { return m.id == id; });
    if (!served) {
      return usage_error(command_line, "--lss-module " + std::to_string(id) +
                                           ": not the id of a module in " +
                                           command_line.config_path);
    }
    options.lss_module = id;
  }
  return canbridge::bridge::run_gateway(options, reload);
}

}  // namespace

int main(int argc, char** argv) {
  const CommandLine command_line = canbridge::bridge::parse_command_line(
      std::vector<std::string>(argv + 1, argv + argc), CANBRIDGE_CONFIG_DIR, CANBRIDGE_VERSION);
  switch (command_line.command) {
    case Command::done:
      std::cout << command_line.output;
      if (!command_line.error.empty()) print_error(command_line.log_format, command_line.error);
      return command_line.exit_status;
    case Command::client:
      return canbridge::cli::run_client(command_line.client_args, std::cout, std::cerr,
                                        ::isatty(STDOUT_FILENO) == 1);
    case Command::check:
      return canbridge::bridge::check_config(command_line.config_path, std::cout, std::cerr);
    case Command::demo:
    case Command::gateway:
    case Command::surface:
      break;
  }
  canbridge::logging::setup_logging(command_line.log_format);
  try {
    if (command_line.command == Command::demo) {
      return canbridge::bridge::run_demo(command_line.demo);
    }
    return run_role(command_line);
  } catch (const canbridge::config::ConfigError& e) {
    print_error(command_line.log_format, std::string("canbridge: ") + e.what());
    return 2;
  } catch (const std::exception& e) {
    print_error(command_line.log_format, std::string("canbridge: ") + e.what());
    return 1;
  }
}
