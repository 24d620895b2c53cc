// canbridge: the command-line entry point of every role (gateway, surface, demo).
#include <spdlog/spdlog.h>

#include <cstring>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "bridge/demo.hpp"
#include "bridge/run_roles.hpp"
#include "config/loader.hpp"

namespace {

constexpr const char* kUsage = R"(usage:
  canbridge demo [--modules N] [--nodes N]
      the gateway and surface roles in one process, on virtual buses and a loopback TCP
      backbone, with simulated CANopen nodes: prints the node table, SDO reads and counters
  canbridge gateway --config FILE    module buses <-> backbone (see config/gateway.yaml)
  canbridge surface --config FILE    backbone <-> one surface CAN interface (config/surface.yaml)
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
  spdlog::set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  try {
    if (command == "gateway" || command == "surface") {
      if (args.size() != 3 || args[1] != "--config") {
        return usage_error(command + " needs exactly --config FILE");
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
