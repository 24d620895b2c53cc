// Runs Debian's tshark on a capture file with the CANopen dissector selected, for the tests that
// prove a capture opens in Wireshark (the command is the one docs/remote-access.md gives).
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>

#include "tests/support/process.hpp"

namespace canbridge::test {

// The tshark on PATH, or "" (tools/install-deps.sh installs it).
inline std::string find_tshark() {
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const auto candidate = std::filesystem::path(dir) / "tshark";
    if (!dir.empty() && ::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return {};
}

// `tshark -r FILE -V -d can.subdissector,canopen`: SocketCAN captures carry no hint of the
// protocol above CAN, so the CANopen dissector is chosen with "Decode As".
inline RunResult run_tshark_canopen(const std::string& tshark, const std::string& file) {
  return run({tshark, "-r", file, "-V", "-d", "can.subdissector,canopen"},
             std::chrono::milliseconds(30000));
}

}  // namespace canbridge::test
