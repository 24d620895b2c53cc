// canbridge: the command-line entry point of every role (gateway, surface, demo).
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "app/cli_main.hpp"
#include "app/demo.hpp"
#include "app/run_roles.hpp"
#include "config/loader.hpp"

namespace {

constexpr const char* kUsage = R"(usage:
  canbridge demo [--modules N] [--nodes N]
      the gateway and surface roles in one process, on virtual buses and a loopback TCP
      backbone, with simulated CANopen nodes: prints the node table, SDO reads and counters
  canbridge gateway --config FILE [--lss-module ID]
                                     module buses <-> backbone (see config/gateway.yaml);
                                     LSS goes to module ID only
  canbridge surface --config FILE    backbone <-> one surface CAN interface (config/surface.yaml)
  canbridge nodes | sdo | nmt | set-node-id | flash | dump | capture  [--endpoint PATH|HOST:PORT]
      [--token-file F] [-c surface.yaml] [--net N]   operator commands against a running
      surface's command endpoint; canbridge SUBCOMMAND --help for each
  canbridge --help | --version
)";

int usage_error(const std::string& message) {
  std::cerr << "canbridge: " << message << "\n" << kUsage;
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty()) return usage_error("no command given");
  const std::string command = args[0];
  if (command == "--help" || command == "-h") {
    std::cout << kUsage;
    return 0;
  }
  if (command == "--version") {
    std::cout << "canbridge " << CANBRIDGE_VERSION << "\n";
    return 0;
  }
  if (canbridge::cli::is_client_command(command)) {
    return canbridge::cli::run_client(args, std::cout, std::cerr, ::isatty(STDOUT_FILENO) == 1);
  }
  spdlog::set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  try {
    if (command == "gateway" && args.size() == 5 && args[1] == "--config" &&
        args[3] == "--lss-module") {
      auto options = canbridge::config::load_gateway(args[2]);
      // A commissioning session picks the bus LSS reaches without editing the file.
      std::uint32_t id = 0;
      const std::string& text = args[4];
      const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), id);
      const bool served = std::any_of(options.modules.begin(), options.modules.end(),
                                      [&](const auto& m) { return m.id == id; });
      if (ec != std::errc{} || end != text.data() + text.size() || !served) {
        return usage_error("--lss-module " + text + ": not the id of a module in " + args[2]);
      }
      options.lss_module = id;
      return canbridge::bridge::run_gateway(options);
    }
    if (command == "gateway" || command == "surface") {
      if (args.size() != 3 || args[1] != "--config") {
        return usage_error(command + " needs exactly --config FILE" +
                           (command == "gateway" ? " [--lss-module ID]" : ""));
      }
      if (command == "gateway") {
        return canbridge::bridge::run_gateway(canbridge::config::load_gateway(args[2]));
      }
      return canbridge::bridge::run_surface(canbridge::config::load_surface(args[2]));
    }
    if (command == "demo") {
      canbridge::bridge::DemoOptions demo;
      for (std::size_t i = 1; i < args.size(); i += 2) {
        if (i + 1 >= args.size()) return usage_error(args[i] + " needs a value");
        const int value = std::atoi(args[i + 1].c_str());
        if (args[i] == "--modules" && value >= 1 && value <= 4) {
          demo.modules = static_cast<unsigned>(value);
        } else if (args[i] == "--nodes" && value >= 1 && value <= 31) {
          demo.nodes_per_module = static_cast<unsigned>(value);
        } else {
          return usage_error("bad demo option " + args[i] + " " + args[i + 1] +
                             " (--modules 1..4, --nodes 1..31)");
        }
      }
      return canbridge::bridge::run_demo(demo);
    }
    return usage_error("unknown command '" + command + "'");
  } catch (const canbridge::config::ConfigError& e) {
    std::cerr << "canbridge: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "canbridge: " << e.what() << "\n";
    return 1;
  }
}
