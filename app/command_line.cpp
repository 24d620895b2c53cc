#include "app/command_line.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <filesystem>

#include "app/cli_main.hpp"

namespace canbridge::bridge {

namespace {

constexpr std::string_view kOperatorCommands =
    "Operator commands against a running surface's command endpoint (each has --help):\n"
    "  nodes, sdo, nmt, set-node-id, flash, dump, capture\n"
    "  canbridge SUBCOMMAND [--endpoint PATH|HOST:PORT] [--token-file F] [-c surface.yaml] "
    "[--net N] ...\n";

constexpr std::string_view kRoles =
    "gateway, surface, demo or an operator command (nodes, sdo, "
    "nmt, set-node-id, flash, dump, capture)";

// The log options every role shares: -v, --log-level, --log-format.
struct LogArguments {
  int verbosity = 0;
  std::string level;
  std::string format = "auto";
};

void add_log_options(CLI::App& role, LogArguments& log) {
  auto* verbose = role.add_flag("-v,--verbose", log.verbosity,
                                "more log: -v debug, -vv trace (overrides the file's log.level)");
  role.add_option("--log-level", log.level,
                  "trace|debug|info|warn|error|off (overrides the file's log.level, also on "
                  "SIGHUP)")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}))
      ->excludes(verbose);
  role.add_option("--log-format", log.format,
                  "auto|text|journal: journal = sd-daemon priority prefixes, no timestamps; auto "
                  "picks journal when stderr is the journal (default auto)")
      ->check(CLI::IsMember({"auto", "text", "journal"}));
}

CommandLine finished(int status, std::string output, std::string error) {
  CommandLine result;
  result.command = Command::done;
  result.exit_status = status;
  result.output = std::move(output);
  result.error = std::move(error);
  return result;
}

CommandLine usage_error(const std::string& message, const std::string& help_command) {
  return finished(2, {},
                  "canbridge: " + message + "\nrun '" + help_command + " --help' for the usage\n");
}

}  // namespace

std::string default_config_path(std::string_view config_dir, Command role) {
  return (std::filesystem::path(config_dir) /
          (role == Command::gateway ? "gateway.yaml" : "surface.yaml"))
      .string();
}

std::optional<std::string> missing_default_config(const CommandLine& command_line) {
  if (command_line.config_given) return std::nullopt;
  if (command_line.command != Command::gateway && command_line.command != Command::surface) {
    return std::nullopt;
  }
  std::error_code ec;
  if (std::filesystem::exists(command_line.config_path, ec)) return std::nullopt;
  return "no --config given and the default " + command_line.config_path +
         " does not exist: install it there or pass --config FILE";
}

CommandLine parse_command_line(const std::vector<std::string>& args, std::string_view config_dir,
                               std::string_view version) {
  const std::string version_line = "canbridge " + std::string(version) + "\n";
  // The operator subcommands have their own parser (cli_main); --version is the one option
  // they share with every other command.
  if (!args.empty() && cli::is_client_command(args.front())) {
    if (std::find(args.begin(), args.end(), "--version") != args.end()) {
      return finished(0, version_line, {});
    }
    CommandLine result;
    result.command = Command::client;
    result.client_args = args;
    return result;
  }
  if (!args.empty() && !args.front().empty() && args.front().front() != '-' &&
      args.front() != "gateway" && args.front() != "surface" && args.front() != "demo") {
    return usage_error("unknown command '" + args.front() + "': expected " + std::string(kRoles),
                       "canbridge");
  }

  CLI::App app{"canbridge: CANopen buses tunnelled over a TCP or serial backbone", "canbridge"};
  app.set_version_flag("--version", version_line.substr(0, version_line.size() - 1),
                       "print the version and exit");
  app.require_subcommand(1, 1);
  app.footer(std::string(kOperatorCommands));

  CommandLine result;
  LogArguments log;
  std::uint32_t lss_module = 0;

  const std::string gateway_default = default_config_path(config_dir, Command::gateway);
  auto* gateway = app.add_subcommand(
      "gateway", "module buses <-> backbone: runs on the tool's CAN gateway (config/gateway.yaml)");
  auto* gateway_config = gateway
                             ->add_option("-c,--config", result.config_path,
                                          "the gateway's file (default " + gateway_default + ")")
                             ->type_name("FILE");
  auto* lss = gateway
                  ->add_option("--lss-module", lss_module,
                               "route LSS to this module only (a module id of the file; "
                               "overrides its lss_module)")
                  ->type_name("ID");
  add_log_options(*gateway, log);
  gateway->footer(
      "SIGHUP re-reads the file: log.level and log.stats_interval_s apply at once, "
      "the log names any other change that needs a restart.");
  gateway->fallthrough();  // --version after the subcommand

  const std::string surface_default = default_config_path(config_dir, Command::surface);
  auto* surface = app.add_subcommand(
      "surface", "backbone <-> one surface CAN interface: runs on the PC (config/surface.yaml)");
  auto* surface_config = surface
                             ->add_option("-c,--config", result.config_path,
                                          "the surface's file (default " + surface_default + ")")
                             ->type_name("FILE");
  add_log_options(*surface, log);
  surface->footer(gateway->get_footer());
  surface->fallthrough();

  auto* demo = app.add_subcommand(
      "demo",
      "the gateway and surface roles in one process, on virtual buses and a loopback TCP "
      "backbone, with simulated CANopen nodes: prints the node table, SDO reads and counters");
  demo->add_option("--modules", result.demo.modules, "modules, each its own virtual bus (1..4)")
      ->check(CLI::Range(1, 4));
  demo->add_option("--nodes", result.demo.nodes_per_module, "simulated nodes per module (1..31)")
      ->check(CLI::Range(1, 31));
  demo->fallthrough();

  try {
    app.parse(std::vector<std::string>(args.rbegin(), args.rend()));
  } catch (const CLI::CallForHelp&) {
    return finished(0, app.help(), {});
  } catch (const CLI::CallForVersion& e) {
    return finished(0, std::string(e.what()) + "\n", {});
  } catch (const CLI::ParseError& e) {
    std::string command = "canbridge";
    for (const CLI::App* sub : app.get_subcommands()) command += " " + sub->get_name();
    std::string message = e.what();
    if (dynamic_cast<const CLI::ExtrasError*>(&e) != nullptr) {
      // CLI11 lists them backwards (it parses a reversed vector): name them as given.
      message = "unexpected argument(s):";
      for (const std::string& extra : app.remaining()) message += " " + extra;
    }
    if (dynamic_cast<const CLI::ConversionError*>(&e) != nullptr) message += ": expected a number";
    if (app.get_subcommands().empty() && message.find("subcommand") != std::string::npos) {
      message = "no command given: expected " + std::string(kRoles);
    }
    return usage_error(message, command);
  }

  if (gateway->parsed()) {
    result.command = Command::gateway;
  } else if (surface->parsed()) {
    result.command = Command::surface;
  } else {
    result.command = Command::demo;
    return result;
  }
  result.config_given = gateway_config->count() + surface_config->count() > 0;
  if (!result.config_given) result.config_path = default_config_path(config_dir, result.command);
  if (lss->count() > 0) result.lss_module = lss_module;
  if (!log.level.empty()) {
    result.log_level = log.level;
  } else if (log.verbosity > 0) {
    result.log_level = log.verbosity == 1 ? "debug" : "trace";
  }
  result.log_format = *logging::parse_log_format(log.format);  // checked by IsMember
  return result;
}

}  // namespace canbridge::bridge
