#include "app/command_line.hpp"

#include <CLI/CLI.hpp>
#include <algorithm>
#include <filesystem>

#include "app/cli_main.hpp"
#include "logging/command_line_common.hpp"

namespace canbridge::bridge {

namespace {

constexpr std::string_view kOperatorCommands =
    "Operator commands against a running surface's command endpoint (each has --help):\n"
    "  nodes, sdo, nmt, set-node-id, flash, dump, capture, stats\n"
    "  canbridge SUBCOMMAND [--endpoint PATH|HOST:PORT] [--token-file F] [-c surface.yaml] "
    "[--net N] ...\n";

constexpr std::string_view kRoles =
    "gateway, surface, demo, check or an operator command (nodes, sdo, "
    "nmt, set-node-id, flash, dump, capture, stats)";

constexpr std::string_view kOrder =
    "Options may stand before or after the command name: 'canbridge -c F gateway' is "
    "'canbridge gateway -c F'. An option that takes one value may be given once (before or "
    "after, not both); -v counts wherever it stands.";

constexpr std::string_view kRoleLogNote = " (overrides the file's log.level, also on SIGHUP)";

// The role parsers' option of this name ("-c", "--config"), or null.
const CLI::Option* role_option(const std::vector<const CLI::App*>& roles, const std::string& name) {
  for (const CLI::App* role : roles) {
    if (const CLI::Option* option = role->get_option_no_throw(name)) return option;
  }
  return nullptr;
}

// Where the command name stands in `args` (args.size() when there is none): the first word that
// is neither an option nor the value of one. Whether an option takes a value is asked of the
// parsers that define it, so that "-c gateway.yaml" is not taken for a command.
std::size_t command_position(const std::vector<std::string>& args,
                             const std::vector<const CLI::App*>& roles) {
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& word = args[i];
    if (word == "--") return args.size();
    if (word.size() < 2 || word.front() != '-') return i;
    if (word.find('=') != std::string::npos) continue;  // --config=F carries its value
    const CLI::Option* option = role_option(roles, word);
    const bool takes_value =
        (option != nullptr && option->get_type_size_min() > 0 && option->get_expected_min() > 0) ||
        cli::is_client_option_with_value(word);
    if (takes_value) ++i;
  }
  return args.size();
}

// " (--lss-module is an option of gateway only)" for the unexpected options that another role
// has, so that a refusal says where the option belongs.
std::string whose_options(const std::vector<std::string>& extras, const CLI::App& refused,
                          const std::vector<const CLI::App*>& roles) {
  std::string note;
  for (const std::string& extra : extras) {
    if (extra.size() < 2 || extra.front() != '-') continue;
    const std::string name = extra.substr(0, extra.find('='));
    std::string owners;
    for (const CLI::App* role : roles) {
      if (role == &refused || role->get_option_no_throw(name) == nullptr) continue;
      owners += (owners.empty() ? "" : ", ") + role->get_name();
    }
    if (!owners.empty()) note += " (" + name + " is an option of " + owners + " only)";
  }
  return note;
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

  CLI::App app{"canbridge: CANopen buses tunnelled over a TCP or serial backbone", "canbridge"};
  app.set_version_flag("--version", version_line.substr(0, version_line.size() - 1),
                       "print the version and exit");
  app.require_subcommand(1, 1);
  app.footer(std::string(kOrder) + "\n\n" + std::string(kOperatorCommands));

  CommandLine result;
  logging::LogArguments log;
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
  logging::add_log_options(*gateway, log, kRoleLogNote);
  gateway->footer(
      "SIGHUP re-reads the file: log.level and log.stats_interval_s apply at once, "
      "the log names any other change that needs a restart.\n" +
      std::string(kOrder));
  gateway->fallthrough();  // --version after the subcommand

  const std::string surface_default = default_config_path(config_dir, Command::surface);
  auto* surface = app.add_subcommand(
      "surface", "backbone <-> one surface CAN interface: runs on the PC (config/surface.yaml)");
  auto* surface_config = surface
                             ->add_option("-c,--config", result.config_path,
                                          "the surface's file (default " + surface_default + ")")
                             ->type_name("FILE");
  logging::add_log_options(*surface, log, kRoleLogNote);
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
  demo->footer(
      "Options may stand before or after the command name: 'canbridge --nodes 8 demo' is "
      "'canbridge demo --nodes 8'. Each may be given once.");
  demo->fallthrough();

  auto* check = app.add_subcommand(
      "check",
      "validate a configuration file of either role (its role: key says which) and the key "
      "files it names, without opening an interface or a socket; exit 0 when valid, 2 otherwise");
  auto* check_config = check
                           ->add_option("-c,--config", result.config_path,
                                        "the file to check (default " + gateway_default + ")")
                           ->type_name("FILE");
  check->fallthrough();

  const std::vector<const CLI::App*> roles = {gateway, surface, demo, check};
  const std::size_t at = command_position(args, roles);
  if (at < args.size() && cli::is_client_command(args[at])) {
    // The operator commands have their own parser (cli_main), which takes its common options
    // before the name too; --version is the one option they share with every other command.
    if (std::find(args.begin(), args.end(), "--version") != args.end()) {
      return finished(0, version_line, {});
    }
    result.command = Command::client;
    result.client_args = args;
    return result;
  }
  const bool is_role = at < args.size() && std::any_of(roles.begin(), roles.end(), [&](auto* r) {
                         return r->check_name(args[at]);
                       });
  if (at < args.size() && !is_role) {
    return usage_error("unknown command '" + args[at] + "': expected " + std::string(kRoles),
                       "canbridge");
  }
  // The options before the command name are the command's: CLI11 reads a subcommand's options
  // after its name, so they move there, ahead of the ones given after it. (CLI11 takes the
  // arguments as a reversed vector: it pops them from the back.)
  std::vector<std::string> ordered;
  ordered.reserve(args.size());
  if (at < args.size()) ordered.push_back(args[at]);
  for (std::size_t i = 0; i < args.size(); ++i) {
    if (i != at) ordered.push_back(args[i]);
  }

  try {
    app.parse(std::vector<std::string>(ordered.rbegin(), ordered.rend()));
  } catch (const CLI::CallForHelp&) {
    return finished(0, app.help(), {});
  } catch (const CLI::CallForVersion& e) {
    return finished(0, std::string(e.what()) + "\n", {});
  } catch (const CLI::ParseError& e) {
    std::string command = "canbridge";
    for (const CLI::App* sub : app.get_subcommands()) command += " " + sub->get_name();
    std::string message = logging::usage_message(app, e);
    if (dynamic_cast<const CLI::ExtrasError*>(&e) != nullptr && !app.get_subcommands().empty()) {
      message += whose_options(app.remaining(), *app.get_subcommands().front(), roles);
    }
    if (app.get_subcommands().empty() && message.find("subcommand") != std::string::npos) {
      message = "no command given: expected " + std::string(kRoles);
    }
    // The error is written in the --log-format read before the bad argument, if any.
    CommandLine refused = usage_error(message, command);
    refused.log_format = log.log_format();
    return refused;
  }
  if (check->parsed()) {
    result.command = Command::check;
    result.config_given = check_config->count() > 0;
    if (!result.config_given) result.config_path = gateway_default;
    return result;
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
  result.log_level = log.log_level();
  result.log_format = log.log_format();
  return result;
}

}  // namespace canbridge::bridge
