// End-to-end: the surface on vcan0 and a gateway on vcan1 + vcan2 run as real processes, started
// once for the suite; frames are injected with can-utils' cansend and observed on independent raw
// sockets opened per test. Startup errors are checked against processes of their own.
#include <gtest/gtest.h>

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
using test::Capture;
using test::ChildProcess;
using test::last_line;
using test::RawCanSocket;
using test::receive_until;

// Longest wait for the next frame on a bus. Wherever a test reads up to a marker, a frame routed
// elsewhere never shows up before the marker, because each bus is strictly FIFO through the
// tunnel.
constexpr std::chrono::milliseconds kGap = 5000ms;

// In a directory of this process's own: the rig's guests share the host's /tmp, and tests that
// run at the same time must not read each other's configs.
std::string write_file(const std::string& name, const std::string& text) {
  static test::TempKeyDir dir;
  return dir.file(name, text, 0644);
}

void cansend(const std::string& bus, const std::string& frame) {
  auto r = test::run({"cansend", bus, frame});
  ASSERT_EQ(r.status, 0) << "cansend " << bus << " " << frame << ": " << r.output;
}

class Tunnel : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    // Port 0: the surface picks a free port and logs it, so nothing can take it in between.
    const std::string surface_cfg =
        write_file("surface.yaml",
                   "role: surface\nname: test-surface\nbus: vcan0\nbackbone:\n  listen: "
                   "127.0.0.1:0\n  auth: {mode: plain}\n"
                   "gateways: [{name: test-gateway, modules: [1, 2]}]\nlog:\n  level: info\n");
    surface_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "surface", "--config", surface_cfg});
    ASSERT_TRUE(surface_->wait_for_line("listening on 127.0.0.1:", 10s)) << surface_->output();
    std::smatch port;
    const std::string out = surface_->output();
    ASSERT_TRUE(std::regex_search(out, port, std::regex("listening on 127\\.0\\.0\\.1:([0-9]+)")))
        << out;
    const std::string gateway_cfg = write_file(
        "gateway.yaml",
        "role: gateway\nname: test-gateway\nbackbone:\n  connect: "
        "127.0.0.1:" +
            port[1].str() +
            "\n  auth: {mode: plain}\n  reconnect_min_ms: 20\nmodules:\n  - id: 1\n    bus: "
            "vcan1\n  - id: 2\n    bus: vcan2\n");
    gateway_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", gateway_cfg});
    ASSERT_TRUE(surface_->wait_for_line("gateway 'test-gateway' ready", 10s))
        << surface_->output() << gateway_->output();
    ASSERT_TRUE(gateway_->wait_for_line("surface 'test-surface' ready", 10s)) << gateway_->output();
    // A plain backbone never runs silently.
    EXPECT_NE(surface_->output().find("backbone is NOT authenticated"), std::string::npos)
        << surface_->output();
    EXPECT_NE(gateway_->output().find("backbone is NOT authenticated"), std::string::npos)
        << gateway_->output();
    ready_ = true;
  }

  // On SIGTERM both processes exit 0, and the last thing each prints is its counter line, with
  // the traffic of the whole suite (at least the fences) counted.
  static void TearDownTestSuite() {
    if (gateway_) {
      EXPECT_EQ(gateway_->stop(), 0) << gateway_->output();
      const std::string line = last_line(gateway_->output());
      std::smatch m;
      EXPECT_TRUE(std::regex_search(
          line, m,
          std::regex("gateway test-gateway: link (up|down), bus->backbone ([0-9]+) frames")))
          << "final line: " << line;
      if (!m.empty()) {
        EXPECT_GT(std::stoull(m[2].str()), 0u) << line;
      }
      EXPECT_NE(line.find("; vcan1 rx "), std::string::npos) << line;
      EXPECT_NE(line.find("; vcan2 rx "), std::string::npos) << line;
    }
    if (surface_) {
      EXPECT_EQ(surface_->stop(), 0) << surface_->output();
      const std::string line = last_line(surface_->output());
      std::smatch m;
      EXPECT_TRUE(
          std::regex_search(line, m,
                            std::regex("surface test-surface: [0-9]+/[0-9]+ gateway\\(s\\) up, "
                                       "bus->backbone ([0-9]+) frames, backbone->bus "
                                       "([0-9]+),")))
          << "final line: " << line;
      if (!m.empty()) {
        EXPECT_GT(std::stoull(m[1].str()), 0u) << line;
        EXPECT_GT(std::stoull(m[2].str()), 0u) << line;
      }
      EXPECT_NE(line.find("; vcan0 rx "), std::string::npos) << line;
    }
    gateway_.reset();
    surface_.reset();
    ready_ = false;
  }

  void SetUp() override {
    ASSERT_TRUE(ready_) << "the surface and gateway did not start";
    ASSERT_FALSE(surface_->finished()) << surface_->output();
    ASSERT_FALSE(gateway_->finished()) << gateway_->output();
    ASSERT_TRUE(fence());
  }

  // The processes outlive each test, so frames of an earlier test may still be in flight. Sends
  // a fresh marker through every direction and reads up to it: each direction of each bus is FIFO
  // through the tunnel, so whatever an earlier test left arrives before the markers.
  bool fence() {
    const std::uint8_t seq = ++fence_seq_;
    const Frame down = Frame::standard(0x000, {0x80, 0x00, seq});  // NMT broadcast: every module
    // Two bytes, so not a heartbeat state: those are conflated and may pass reliable frames,
    // while a fence must keep FIFO order with everything an earlier test left in flight.
    const Frame up1 = Frame::standard(0x701, {seq, 0xFE});  // module 1 node 1's error control id
    const Frame up2 = Frame::standard(0x702, {seq, 0xFE});  // module 2 node 2's
    vcan0_.send(down);
    vcan1_.send(up1);
    vcan2_.send(up2);
    for (RawCanSocket* module_bus : {&vcan1_, &vcan2_}) {
      if (!receive_until(*module_bus, down, kGap).marker_seen) {
        ADD_FAILURE() << "fence marker " << can::to_string(down) << " never reached a module bus\n"
                      << surface_->output() << gateway_->output();
        return false;
      }
    }
    // On the surface: module 1 node 1 = surface node 33, module 2 node 2 = surface node 66.
    bool seen1 = false, seen2 = false;
    while (!(seen1 && seen2)) {
      auto f = vcan0_.receive(5000ms);
      if (!f) {
        ADD_FAILURE() << "fence heartbeats never reached vcan0\n" << gateway_->output();
        return false;
      }
      seen1 = seen1 || *f == Frame::standard(0x721, {seq, 0xFE});
      seen2 = seen2 || *f == Frame::standard(0x742, {seq, 0xFE});
    }
    return true;
  }

  static inline std::unique_ptr<ChildProcess> surface_, gateway_;
  static inline bool ready_ = false;
  static inline std::uint8_t fence_seq_ = 0;
  RawCanSocket vcan0_{"vcan0"}, vcan1_{"vcan1"}, vcan2_{"vcan2"};
};

TEST_F(Tunnel, SdoRequestReachesOnlyTheOwningModuleAndTheReplyComesBackTranslated) {
  cansend("vcan0", "622#4018100100000000");
  cansend("vcan0", "000#8000");  // broadcast marker: reaches every module after the SDO
  const Frame marker = Frame::standard(0x000, {0x80, 0x00});
  const auto at1 = receive_until(vcan1_, marker, kGap);
  const auto at2 = receive_until(vcan2_, marker, kGap);
  ASSERT_TRUE(at1.marker_seen) << "the marker never reached vcan1";
  ASSERT_TRUE(at2.marker_seen) << "the marker never reached vcan2";
  ASSERT_EQ(at1.frames.size(), 2u);
  EXPECT_EQ(at1.frames[0], Frame::standard(0x602, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  ASSERT_EQ(at2.frames.size(), 1u)
      << "the SDO request leaked to vcan2: " << can::to_string(at2.frames[0]);

  cansend("vcan1", "582#4318100178563412");
  const Frame reply = Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 0x78, 0x56, 0x34, 0x12});
  // vcan0 also shows what cansend itself sent there.
  EXPECT_TRUE(receive_until(vcan0_, reply, kGap).marker_seen) << "the reply never reached vcan0";
}

TEST_F(Tunnel, NodeSpecificNmtIsRewrittenAndBroadcastReachesBoth) {
  cansend("vcan0", "000#0122");
  cansend("vcan0", "000#8000");
  const Frame marker = Frame::standard(0x000, {0x80, 0x00});
  const auto at1 = receive_until(vcan1_, marker, kGap);
  const auto at2 = receive_until(vcan2_, marker, kGap);
  ASSERT_TRUE(at1.marker_seen) << "the marker never reached vcan1";
  ASSERT_TRUE(at2.marker_seen) << "the marker never reached vcan2";
  ASSERT_EQ(at1.frames.size(), 2u);
  EXPECT_EQ(at1.frames[0], Frame::standard(0x000, {0x01, 0x02}));
  EXPECT_EQ(at2.frames.size(), 1u);
}

TEST_F(Tunnel, EveryModuleFrameKindCrossesAndUnmappedFramesDoNot) {
  // Module 2 (surface = local + 64): EMCY, TPDO1, heartbeat; a 29-bit frame and a SYNC from a
  // module are not CANopen traffic the surface may see.
  cansend("vcan2", "09F#1122334455667788");  // EMCY of local node 31
  cansend("vcan2", "12345678#00");
  cansend("vcan2", "080#");
  cansend("vcan2", "1BF#01");  // local node 63: outside the default map of local 1..31
  cansend("vcan2", "19F#01020304");
  cansend("vcan2", "71F#05");
  std::vector<Frame> got;
  for (int i = 0; i < 3; ++i) {
    auto f = vcan0_.receive(5000ms);
    ASSERT_TRUE(f) << "frame " << i << " missing\n" << gateway_->output();
    got.push_back(*f);
  }
  EXPECT_EQ(got[0], Frame::standard(0x0DF, {0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88}));
  EXPECT_EQ(got[1], Frame::standard(0x1DF, {1, 2, 3, 4}));
  EXPECT_EQ(got[2], Frame::standard(0x75F, {0x05}));
}

TEST_F(Tunnel, CandumpOnTheModuleBusSeesTheTranslatedFrame) {
  // candump is ready once its socket is bound: wait for it in the kernel's receiver list, so
  // one frame is enough.
  const int before = test::receivers_on("vcan1");
  ChildProcess candump({"candump", "-L", "-n", "1", "vcan1"});
  ASSERT_TRUE(test::wait_for_receivers("vcan1", before, 10s)) << candump.output();
  cansend("vcan0", "23F#CAFE");  // RPDO1 of surface node 63 = module 1 node 31
  ASSERT_TRUE(candump.wait(10s)) << candump.output();
  EXPECT_NE(candump.output().find("vcan1 21F#CAFE"), std::string::npos) << candump.output();
}

// Startup errors: each run is a gateway of its own that must refuse to start.
TEST(TunnelStartup, BadConfigExitsWithStatus2NamingFileLineAndFieldOfEveryProblem) {
  const std::string path = write_file("gateway_bad.yaml",
                                      "role: gateway\n"           // 1
                                      "name: bad-gateway\n"       // 2
                                      "backbone:\n"               // 3
                                      "  connect: 127.0.0.1:1\n"  // 4
                                      "  reconect_min_ms: 20\n"   // 5: unknown key (typo)
                                      "modules:\n"                // 6
                                      "  - id: 1\n"               // 7
                                      "    bus: vcan1\n"          // 8
                                      "  - id: 2\n"               // 9
                                      "    bus: vcan1\n");        // 10: vcan1 again
  auto r = test::run({CANBRIDGE_BIN, "gateway", "--config", path}, 10s, Capture::stderr_only);
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find(path + ":5: backbone.reconect_min_ms: unknown key"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find(path + ":10: modules[1].bus: bus 'vcan1' is used by two modules"),
            std::string::npos)
      << r.output;
  // No auth block: plain operation is never a default.
  EXPECT_NE(r.output.find(path + ":3: backbone.auth: missing (required)"), std::string::npos)
      << r.output;
}

TEST(TunnelStartup, MissingConfigFileExitsNonZeroWithAClearMessage) {
  auto r =
      test::run({CANBRIDGE_BIN, "gateway", "--config", "/nonexistent"}, 10s, Capture::stderr_only);
  EXPECT_NE(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("/nonexistent: cannot open the file"), std::string::npos) << r.output;
}

TEST(TunnelStartup, MissingCanInterfaceExitsNonZeroNamingIt) {
  const std::string path = write_file(
      "gateway_vcan9.yaml",
      "role: gateway\nname: vcan9-gateway\nbackbone:\n  connect: 127.0.0.1:1\n"
      "  auth: {mode: plain}\nmodules:\n  - id: 1\n    bus: vcan1\n  - id: 2\n    bus: vcan9\n");
  auto r = test::run({CANBRIDGE_BIN, "gateway", "--config", path}, 10s, Capture::stderr_only);
  EXPECT_NE(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("'vcan9'"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace canbridge
