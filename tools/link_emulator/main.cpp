// canbridge-link-emulator: a slow, noisy, sometimes cut wireline between two backbone endpoints.
#include <spdlog/spdlog.h>

#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "logging/log_setup.hpp"
#include "tools/link_emulator/command_line.hpp"
#include "tools/link_emulator/link_shell.hpp"

namespace {

// An error written outside the logger: in the journal format every line has the error priority,
// as the logger's own error lines do.
void print_error(canbridge::logging::LogFormat format, const std::string& text) {
  std::cerr << canbridge::logging::prefix_lines(canbridge::logging::resolve(format),
                                                spdlog::level::err, text);
}

}  // namespace

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
    print_error(canbridge::logging::LogFormat::automatic,
                "canbridge-link-emulator: " + command_line.error +
                    "\nrun 'canbridge-link-emulator --help' for the usage");
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
    print_error(command_line.log_format, std::string("canbridge-link-emulator: ") + e.what());
    return 1;
  }
}
