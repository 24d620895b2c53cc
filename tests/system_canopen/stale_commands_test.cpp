// No stale command reaches a node (issue 14), with the real processes of the CANopen transparency
// rig (this directory's configs, the gateway connected straight to the surface):
// - a gateway process frozen (SIGSTOP) for 3 s while the master writes to one of its nodes: the
//   master gets abort 0x05040000 and the node must never execute the write, although the
//   request waits in the gateway's socket when it resumes (SIGCONT); likewise for the segments
//   of a download in progress;
// - a gateway process killed while the master sends NMT stop to its node and an SDO request: a
//   new gateway process gets none of it, so the node keeps running.
// The master is tests/support/sdo_master on vcan0; what reaches the module bus vcan1 is recorded.
// Everything awaited is a frame, a log line or a process state, with a deadline; the only timed
// wait is the freeze itself.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/types.h>
#include <sys/wait.h>

#include <array>
#include <iostream>
#include <regex>
#include <string>
#include <thread>

#include "tests/support/bus_log.hpp"
#include "tests/support/raw_can.hpp"
#include "tests/support/rig_processes.hpp"
#include "tests/support/sdo_master.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::BusLog;
using test::RawCanSocket;
using test::RigProcesses;
using test::SdoMaster;
using test::SdoOutcome;
using Clock = std::chrono::steady_clock;

const std::string kDir = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/system_canopen/";
constexpr auto kEvent = 10s;  // upper bound of one awaited event in the slow UML guest
constexpr auto kFreeze = 3s;  // far beyond dead_after_ms (400) of both configs
constexpr std::uint32_t kLinkDownAbort = 0x05040000;
// rig.yaml's cia301 "device": local 10 on vcan1, surface 42; heartbeat every 100 ms.
constexpr std::uint8_t kSurface = 42;
constexpr std::uint8_t kLocal = 10;
constexpr std::uint32_t kHeartbeatMs = 100;

test::RigOptions rig_options() {
  return {.canbridge = CANBRIDGE_BIN,
          .sim = CANBRIDGE_SIM_BIN,
          .link_emulator = "",
          .link_emulator_args = {},
          .config_dir = kDir,
          .port_placeholder = "${LINK_PORT}",
          .surface_name = "canopen-surface",
          .gateway_name = "canopen-gateway",
          .sim_ready = "ready 6 nodes on 3 buses",
          .event_timeout = kEvent};
}

// The number after `label` in a counter line ("stale-links 1"), or -1.
long long counter(const std::string& line, const std::string& label) {
  std::smatch m;
  if (!std::regex_search(line, m, std::regex(label + " ([0-9]+)"))) return -1;
  return std::stoll(m[1].str());
}

// Blocks until the child `pid` is stopped (WSTOPPED) or continued (WCONTINUED), leaving its
// status for whoever reaps it.
bool wait_child_state(pid_t pid, int state) {
  siginfo_t info{};
  return ::waitid(P_PID, static_cast<id_t>(pid), &info, state | WNOWAIT) == 0;
}

// An SDO request of the master to the node on its own bus: client command specifier `ccs`
// (1 initiate download, 0 download segment, 2 initiate upload).
bool is_request(const Frame& f, std::uint8_t ccs) {
  return !f.is_extended() && f.id == 0x600u + kLocal && f.len == 8 && (f.data[0] >> 5) == ccs;
}

// The next frame on `id` within `timeout` (other frames skipped).
std::optional<Frame> next_on(RawCanSocket& socket, std::uint32_t id, Clock::duration timeout) {
  const auto deadline = Clock::now() + timeout;
  for (auto now = Clock::now(); now < deadline; now = Clock::now()) {
    auto f = socket.receive(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now));
    if (f && !f->is_extended() && f->id == id) return f;
  }
  return std::nullopt;
}

class StaleCommands : public ::testing::Test {
 protected:
  void TearDown() override {
    processes.stop();
    processes.print_logs(HasFailure());
  }

  // Stops the gateway, runs `while_frozen` (the master's part), holds the freeze for kFreeze in
  // all, resumes it and waits until the session is back.
  void freeze_gateway(const std::function<void()>& while_frozen) {
    const pid_t pid = processes.gateway->pid();
    ASSERT_EQ(::kill(pid, SIGSTOP), 0);
    ASSERT_TRUE(wait_child_state(pid, WSTOPPED));
    const auto frozen_at = Clock::now();
    while_frozen();
    ASSERT_TRUE(processes.surface->wait_for_line("link to 'canopen-gateway'", kEvent))
        << processes.surface->output();
    std::this_thread::sleep_until(frozen_at + kFreeze);  // the freeze itself
    ASSERT_EQ(::kill(pid, SIGCONT), 0);
    ASSERT_TRUE(wait_child_state(pid, WCONTINUED));
    ASSERT_TRUE(processes.gateway->wait_for_line("surface 'canopen-surface' ready", kEvent))
        << processes.gateway->output();
    ASSERT_TRUE(processes.surface->wait_for_line("gateway 'canopen-gateway' ready", kEvent))
        << processes.surface->output();
  }

  // The gateway's exit line, after stopping every process.
  std::string stop_and_gateway_counters() {
    processes.stop();
    return processes.gateway_final;
  }

  BusLog module_bus{"vcan1"};
  BusLog surface_bus{"vcan0"};
  RigProcesses processes{rig_options()};
};

TEST_F(StaleCommands, AWriteTheMasterSawAbortedWhileTheGatewayWasFrozenIsNeverExecuted) {
  ASSERT_NO_FATAL_FAILURE(processes.start());
  RawCanSocket socket("vcan0");
  SdoMaster master(socket);
  SdoOutcome o;
  ASSERT_EQ(master.read_u32(kSurface, 0x1017, 0, &o), kHeartbeatMs) << describe(o);
  const std::size_t mark = module_bus.mark();
  SdoOutcome write;
  ASSERT_NO_FATAL_FAILURE(freeze_gateway([&] {
    const std::array<std::uint8_t, 2> slower{0xF4, 0x01};  // 500 ms
    write = master.download(kSurface, 0x1017, 0, slower);
  }));
  EXPECT_TRUE(write.aborted_with(kLinkDownAbort)) << describe(write);
  // The session is back: the node still has the value the master last saw succeed.
  EXPECT_EQ(master.read_u32(kSurface, 0x1017, 0, &o), kHeartbeatMs)
      << "the node executed a write its master was told had failed: " << describe(o);
  std::size_t downloads = 0;
  for (const auto& e : module_bus.entries(mark)) downloads += is_request(e.frame, 1);
  EXPECT_EQ(downloads, 0u) << "the aborted write reached the module bus";
  const std::string gateway = stop_and_gateway_counters();
  std::cout << "[  freeze  ] master's write aborted after " << write.elapsed.count()
            << " ms; gateway: stale-links " << counter(gateway, "stale-links") << ", dead-links "
            << counter(gateway, "dead-links") << "\n";
  EXPECT_EQ(counter(gateway, "stale-links") + counter(gateway, "dead-links"), 1) << gateway;
}

TEST_F(StaleCommands, NoSegmentOfADownloadAbortedWhileTheGatewayWasFrozenReachesTheNode) {
  ASSERT_NO_FATAL_FAILURE(processes.start());
  RawCanSocket socket("vcan0");
  SdoMaster master(socket);
  const std::uint32_t request = 0x600u + kSurface;
  const std::uint32_t response = 0x580u + kSurface;
  // The surface follows transfers of nodes it has seen through their gateway.
  ASSERT_TRUE(surface_bus.wait_for(
      0, [](const Frame& f) { return f.id == 0x700u + kSurface; }, kEvent));
  // Segmented download of 14 bytes to 2001h (a visible string, "initial"): initiate, answered.
  socket.send(Frame::standard(request, {0x21, 0x01, 0x20, 0x00, 14, 0, 0, 0}));
  const auto initiated = next_on(socket, response, kEvent);
  ASSERT_TRUE(initiated);
  ASSERT_EQ(initiated->data[0], 0x60) << can::to_string(*initiated);
  const std::size_t mark = module_bus.mark();
  std::optional<Frame> answer;
  ASSERT_NO_FATAL_FAILURE(freeze_gateway([&] {
    // The first segment (toggle 0, 7 bytes, more to come) while the gateway is stopped.
    socket.send(Frame::standard(request, {0x00, 'r', 'e', 'p', 'l', 'a', 'c', 'e'}));
    answer = next_on(socket, response, kEvent);
  }));
  ASSERT_TRUE(answer);
  EXPECT_EQ(*answer, Frame::standard(response, {0x80, 0x01, 0x20, 0x00, 0x00, 0x00, 0x04, 0x05}))
      << can::to_string(*answer);
  std::size_t segments = 0;
  for (const auto& e : module_bus.entries(mark)) segments += is_request(e.frame, 0);
  EXPECT_EQ(segments, 0u) << "a segment of the aborted download reached the module bus";
  // The node gave up the transfer itself during the freeze (its SDO timeout, abort 2001h); that
  // abort crosses after the gateway resumes, ahead of the node's next heartbeat (arbitration
  // order), and must not be taken for the answer to the read below.
  const std::size_t resumed = surface_bus.mark();
  ASSERT_TRUE(surface_bus.wait_for(
      resumed, [](const Frame& f) { return f.id == 0x700u + kSurface; }, kEvent));
  const SdoOutcome value = master.upload(kSurface, 0x2001, 0);
  ASSERT_TRUE(value.ok()) << describe(value);
  EXPECT_EQ(std::string(value.data.begin(), value.data.end()), "initial");
}

TEST_F(StaleCommands, ANewGatewayProcessGetsNothingQueuedForTheOldOne) {
  ASSERT_NO_FATAL_FAILURE(processes.start());
  RawCanSocket socket("vcan0");
  SdoMaster master(socket);
  const auto operational = [](const Frame& f) {
    return f.id == 0x700u + kSurface && f.len == 1 && f.data[0] == 0x05;
  };
  const std::size_t started = surface_bus.mark();
  socket.send(Frame::standard(0x000, {0x01, kSurface}));  // NMT start
  ASSERT_TRUE(surface_bus.wait_for(started, operational, kEvent));
  // The gateway process dies; the surface sees its link close at once (TCP).
  ASSERT_EQ(::kill(processes.gateway->pid(), SIGKILL), 0);
  ASSERT_TRUE(processes.gateway->wait(kEvent));
  ASSERT_TRUE(processes.surface->wait_for_line("link to 'canopen-gateway'", kEvent))
      << processes.surface->output();
  const std::size_t mark = module_bus.mark();
  socket.send(Frame::standard(0x000, {0x02, kSurface}));  // NMT stop
  // Answered at once; being read after the NMT frame, it also shows that one was taken in.
  const std::array<std::uint8_t, 2> slower{0xF4, 0x01};
  const SdoOutcome write = master.download(kSurface, 0x1017, 0, slower);
  EXPECT_TRUE(write.aborted_with(kLinkDownAbort)) << describe(write);
  ASSERT_NO_FATAL_FAILURE(processes.restart_gateway());
  // Five heartbeat periods after the new session is up: the node is still operational.
  std::size_t from = surface_bus.mark();
  for (int beat = 0; beat < 5; ++beat) {
    const auto found = surface_bus.wait_for(
        from, [](const Frame& f) { return f.id == 0x700u + kSurface && f.len == 1; }, kEvent);
    ASSERT_TRUE(found) << "no heartbeat of node " << int(kSurface);
    EXPECT_TRUE(operational(found->entry.frame))
        << "node stopped by a command sent while its gateway was down: "
        << can::to_string(found->entry.frame);
    from = found->index + 1;
  }
  std::size_t stale = 0;
  for (const auto& e : module_bus.entries(mark)) {
    stale += (e.frame.id == 0x000 && e.frame.len == 2) || is_request(e.frame, 1);
  }
  EXPECT_EQ(stale, 0u) << "a command for the old gateway process reached the module bus";
  processes.stop();
  EXPECT_GE(counter(processes.surface_final, "gateway-restart"), 1) << processes.surface_final;
}

}  // namespace
}  // namespace canbridge
