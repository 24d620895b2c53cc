// canbridge-link-emulator: a slow, noisy, sometimes cut wireline between two backbone endpoints.
#include <spdlog/spdlog.h>

#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "logging/log_setup.hpp"
#include "tools/link_emulator/command_line.hpp"
#include "tools/link_emulator/link_shell.hpp"

int main(int argc, char** argv) {
  const canbridge::emulator::CommandLine command_line =
      canbridge::emulator::parse_command_line(std::vector<std::string>(argv + 1, argv + argc));
  if (command_line.help) {
    std::cout << canbridge::emulator::kUsage;
    return 0;
  }
  if (command_line.version) {
    std::cout << "canbridge-link-emulator " << CANBRIDGE_VERSION << "\n";
    return 0;
  }
  if (!command_line.options) {
    std::cerr << "canbridge-link-emulator: " << command_line.error
              << "\nrun 'canbridge-link-emulator --help' for the usage\n";
    return 2;
  }
  // stdout is for the lines tests wait for (ready, cuts, stats); diagnostics go to stderr.
  canbridge::logging::setup_logging(
      command_line.log_format,
      canbridge::logging::parse_level(command_line.log_level.value_or("info"))
          .value_or(spdlog::level::info));
  try {
    return canbridge::emulator::run_link_emulator(*command_line.options);
  } catch (const std::exception& e) {
    std::cerr << "canbridge-link-emulator: " << e.what() << "\n";
    return 1;
  }
}
