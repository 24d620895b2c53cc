// The canbridge executable's command line, parsed (CLI11) into what main runs: a role (gateway,
// surface, demo) with its options, an operator subcommand handed to cli_main, or text to print
// and an exit status (help, version, usage errors).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "app/demo.hpp"
#include "logging/log_setup.hpp"

namespace canbridge::bridge {

enum class Command {
  gateway,
  surface,
  demo,
  check,   // validate config_path (either role) without opening interfaces or sockets
  client,  // an operator subcommand (nodes, sdo, ...): client_args go to cli::run_client
  done,    // nothing to run: print `output` and `error`, exit with exit_status
};

struct CommandLine {
  Command command = Command::done;
  int exit_status = 0;  // done: 0 after help or version, 2 after a usage error
  std::string output;   // done: for stdout (help, version)
  std::string error;    // done: for stderr (what was wrong and what was expected)

  // gateway, surface: --config/-c, else the role's default file under the config directory.
  std::string config_path;
  bool config_given = false;
  std::optional<std::uint32_t> lss_module;  // gateway: --lss-module
  // -v (debug), -vv (trace) or --log-level: overrides the file's log.level, also on reload.
  std::optional<std::string> log_level;
  logging::LogFormat log_format = logging::LogFormat::automatic;

  DemoOptions demo;
  std::vector<std::string> client_args;  // client: argv without the program
};

// `config_dir`: where the roles' default files live (<sysconfdir>/canbridge); `version` is what
// --version prints after "canbridge ". `args`: argv without the program.
CommandLine parse_command_line(const std::vector<std::string>& args, std::string_view config_dir,
                               std::string_view version);

// The default file of a role: CONFIG_DIR/gateway.yaml or CONFIG_DIR/surface.yaml.
std::string default_config_path(std::string_view config_dir, Command role);

// A usage error when no --config was given and the default file does not exist (nullopt
// otherwise): a role must not start from a file nobody named without saying so.
std::optional<std::string> missing_default_config(const CommandLine& command_line);

}  // namespace canbridge::bridge
