// Starts and stops the real processes of a rig system test (canbridge surface, optionally
// canbridge-link-emulator, canbridge gateway, canbridge-sim): each start awaited with a deadline,
// each exit status checked, the final counter lines and the output kept.
#pragma once

#include <chrono>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "tests/support/process.hpp"

namespace canbridge::test {

struct RigOptions {
  // The binaries: compile definitions of each test target, so passed in.
  std::string canbridge;
  std::string sim;
  // Empty: the gateway connects straight to the surface. Otherwise the link emulator sits between
  // them (a: the gateway's side, b: the surface's), with `link_emulator_args` added, e.g. a cut.
  std::string link_emulator;
  std::vector<std::string> link_emulator_args;
  // Holds surface.yaml, gateway.yaml and rig.yaml (for the sim); ends with '/'.
  std::string config_dir;
  // In gateway.yaml as "127.0.0.1:<placeholder>": replaced by the port the gateway connects to.
  std::string port_placeholder;
  // The names each end reports as "... '<name>' ready" once the session is up.
  std::string surface_name;
  std::string gateway_name;
  // What the sim prints once its nodes are up, after "canbridge-sim: ".
  std::string sim_ready;
  // Upper bound of each awaited step.
  std::chrono::milliseconds event_timeout;
};

class RigProcesses {
 public:
  explicit RigProcesses(RigOptions options) : options_(std::move(options)) {}

  // Starts the surface, then the link emulator if any, then the gateway, and once both ends report
  // the session ready, the simulated nodes, so that their boot-ups cross too. Reports failures
  // with gtest assertions: call under ASSERT_NO_FATAL_FAILURE.
  void start();
  // A new gateway process in place of the one that was killed (reaped already), with the same
  // configuration; returns once both ends report the session ready. Gtest assertions, like
  // start().
  void restart_gateway();
  // Every process started and still running (a fatal failure otherwise).
  void expect_running() const;
  // SIGTERM to each (sim, gateway, surface, emulator), each must exit 0; keeps their output and
  // the final counter lines of gateway and surface.
  void stop();
  // The stopped processes' output, for failures (or always with CANBRIDGE_SHOW_LOGS=1).
  void print_logs(bool failed) const;

  std::unique_ptr<ChildProcess> surface, emulator, gateway, sim;
  std::chrono::steady_clock::time_point emulator_ready;  // when the link emulator said so
  std::string gateway_final, surface_final;              // last lines, set by stop()

 private:
  void start_gateway();
  RigOptions options_;
  std::string dir_;  // the gateway's config with the port filled in
  std::string logs_;
};

}  // namespace canbridge::test
