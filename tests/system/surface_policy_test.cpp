// Who may speak on the surface bus (issue 15), with real processes on vcan: a rogue gateway
// claiming a down gateway's module is refused and told only "refused", nothing of it reaches the
// surface bus, and the real gateway, restarted, rebinds at once. Plain loopback backbone (TLS is
// another branch); the surface's own filter of a bound gateway's frames is proven in process
// (MemoryRoles.ABoundGatewaysFramesForNodesNotItsOwnNeverReachTheSurfaceBus).
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <memory>
#include <regex>

#include "tests/support/process.hpp"
#include "tests/support/raw_can.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::ChildProcess;
using test::RawCanSocket;
using test::receive_until;

// In a directory of this process's own: the rig's guests share the host's /tmp, and tests that
// run at the same time must not read each other's configs.
std::string write_file(const std::string& name, const std::string& text) {
  static test::TempKeyDir dir;
  return dir.file(name, text, 0644);
}

// A gateway process named `name` serving module 1 on `bus`, connecting to `port`.
std::unique_ptr<ChildProcess> gateway(const std::string& name, const std::string& bus,
                                      const std::string& port) {
  const std::string cfg = write_file(
      name + ".yaml", "role: gateway\nname: " + name + "\nbackbone:\n  connect: 127.0.0.1:" + port +
                          "\n  auth: {mode: plain}\n  reconnect_min_ms: 20\n  reconnect_max_ms: "
                          "100\nmodules:\n  - id: 1\n    bus: " +
                          bus + "\n");
  std::vector<std::string> argv{CANBRIDGE_BIN, "gateway", "--config", cfg};
  return std::make_unique<ChildProcess>(std::move(argv));
}

TEST(SurfacePolicy, ARogueClaimingADownGatewaysModuleIsRefusedAndTheRealOneRebindsAtOnce) {
  const std::string surface_cfg = write_file(
      "policy-surface.yaml",
      "role: surface\nname: policy-surface\nbus: vcan0\nbackbone:\n  listen: 127.0.0.1:0\n"
      "  auth: {mode: plain}\ngateways:\n  - {name: real-gw, modules: [1]}\n"
      "  - {name: other-gw, modules: [2]}\nlog:\n  level: info\n");
  ChildProcess surface({CANBRIDGE_BIN, "surface", "--config", surface_cfg});
  ASSERT_TRUE(surface.wait_for_line("bus vcan0, listening on 127.0.0.1:", 10s)) << surface.output();
  std::smatch m;
  const std::string out = surface.output();
  ASSERT_TRUE(
      std::regex_search(out, m, std::regex("bus vcan0, listening on 127\\.0\\.0\\.1:([0-9]+)")));
  const std::string port = m[1].str();
  RawCanSocket vcan0("vcan0"), vcan1("vcan1"), vcan2("vcan2");

  auto real = gateway("real-gw", "vcan1", port);
  ASSERT_TRUE(surface.wait_for_line("gateway 'real-gw' ready", 10s))
      << surface.output() << real->output();
  ASSERT_EQ(real->stop(), 0) << real->output();  // the real gateway is down

  // Two rogues for module 1: another configured gateway's identity, and a name not configured.
  auto other = gateway("other-gw", "vcan2", port);
  auto stranger = gateway("stranger-gw", "vcan2", port);
  ASSERT_TRUE(other->wait_for_line("refused this gateway: refused (REASON_UNSPECIFIED)", 10s))
      << other->output();
  ASSERT_TRUE(stranger->wait_for_line("refused this gateway: refused (REASON_UNSPECIFIED)", 10s))
      << stranger->output();
  // The details are in the surface's log only.
  EXPECT_NE(surface.output().find("'other-gw' announces module 1"), std::string::npos)
      << surface.output();
  EXPECT_EQ(other->output().find("real-gw"), std::string::npos) << other->output();
  // A rogue's module bus traffic reaches nothing (0x705 would be surface 0x725).
  vcan2.send(Frame::standard(0x705, {0x05}));

  // The real gateway returns and is bound at once, rogues still knocking.
  const auto restarted = std::chrono::steady_clock::now();
  real = gateway("real-gw", "vcan1", port);
  ASSERT_TRUE(real->wait_for_line("surface 'policy-surface' ready", 10s)) << real->output();
  const auto rebind = std::chrono::steady_clock::now() - restarted;
  std::printf("real gateway rebound %lld ms after its restart, two rogues refused meanwhile\n",
              static_cast<long long>(
                  std::chrono::duration_cast<std::chrono::milliseconds>(rebind).count()));
  EXPECT_LT(rebind, 2s);

  // Its module bus's own NMT and SYNC never cross; its node's heartbeat does, and is the marker:
  // the rogue's forged heartbeat, sent earlier, would have come before it.
  vcan1.send(Frame::standard(0x000, {0x81, 0x00}));
  vcan1.send(Frame::standard(0x080, {}));
  const Frame marker = Frame::standard(0x726, {0x7F});
  vcan1.send(Frame::standard(0x706, {0x7F}));
  const auto seen = receive_until(vcan0, marker, 5000ms);
  ASSERT_TRUE(seen.marker_seen) << surface.output() << real->output();
  for (const Frame& f : seen.frames) {
    EXPECT_EQ(f, marker) << "on the surface bus: " << can::to_string(f);
  }
  EXPECT_EQ(stranger->stop(), 0);
  EXPECT_EQ(other->stop(), 0);
  EXPECT_EQ(real->stop(), 0);
  EXPECT_EQ(surface.stop(), 0) << surface.output();
  const std::string last = test::last_line(surface.output());
  // The stranger knocked again and again: counted, one warning.
  EXPECT_TRUE(std::regex_search(last, std::regex("refused-strangers [1-9]"))) << last;
}

}  // namespace
}  // namespace canbridge
