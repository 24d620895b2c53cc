// End-to-end: the surface on vcan0 and a gateway on vcan1 + vcan2 run as real processes; frames
// are injected with can-utils' cansend and observed on independent raw sockets.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fstream>
#include <memory>

#include "tests/support/process.hpp"
#include "tests/support/raw_can.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::ChildProcess;
using test::RawCanSocket;

std::uint16_t free_tcp_port() {
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  close(fd);
  return ntohs(a.sin_port);
}

std::string write_file(const std::string& name, const std::string& text) {
  const std::string path = ::testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}

void cansend(const std::string& bus, const std::string& frame) {
  auto r = test::run({"cansend", bus, frame});
  ASSERT_EQ(r.status, 0) << "cansend " << bus << " " << frame << ": " << r.output;
}

// Frames on `socket` until `marker` (inclusive); a frame routed elsewhere never shows up before
// the marker, because each bus is strictly FIFO through the tunnel.
std::vector<Frame> until(RawCanSocket& socket, const Frame& marker) {
  std::vector<Frame> seen;
  while (auto f = socket.receive(5000ms)) {
    seen.push_back(*f);
    if (*f == marker) return seen;
  }
  ADD_FAILURE() << "marker " << can::to_string(marker) << " never arrived";
  return seen;
}

class Tunnel : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::uint16_t port = free_tcp_port();
    const std::string surface_cfg = write_file(
        "surface.yaml",
        "role: surface\nname: test-surface\nbus: vcan0\nbackbone:\n  listen: 127.0.0.1:" +
            std::to_string(port) + "\nlog:\n  level: info\n");
    const std::string gateway_cfg =
        write_file("gateway.yaml",
                   "role: gateway\nname: test-gateway\nbackbone:\n  connect: 127.0.0.1:" +
                       std::to_string(port) +
                       "\n  reconnect_min_ms: 20\nmodules:\n  - id: 1\n    bus: vcan1\n  - id: 2\n"
                       "    bus: vcan2\n");
    surface_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "surface", "--config", surface_cfg});
    ASSERT_TRUE(surface_->wait_for_line("listening", 10s)) << surface_->output();
    gateway_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", gateway_cfg});
    ASSERT_TRUE(surface_->wait_for_line("gateway 'test-gateway' ready", 10s))
        << surface_->output() << gateway_->output();
    ASSERT_TRUE(gateway_->wait_for_line("surface 'test-surface' ready", 10s)) << gateway_->output();
  }
  void TearDown() override {
    EXPECT_EQ(gateway_->stop(), 0) << gateway_->output();
    EXPECT_EQ(surface_->stop(), 0) << surface_->output();
  }
  std::unique_ptr<ChildProcess> surface_, gateway_;
  RawCanSocket vcan0_{"vcan0"}, vcan1_{"vcan1"}, vcan2_{"vcan2"};
};

TEST_F(Tunnel, SdoRequestReachesOnlyTheOwningModuleAndTheReplyComesBackTranslated) {
  cansend("vcan0", "622#4018100100000000");
  cansend("vcan0", "000#8000");  // broadcast marker: reaches every module after the SDO
  const Frame marker = Frame::standard(0x000, {0x80, 0x00});
  auto at1 = until(vcan1_, marker);
  auto at2 = until(vcan2_, marker);
  ASSERT_EQ(at1.size(), 2u);
  EXPECT_EQ(at1[0], Frame::standard(0x602, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  ASSERT_EQ(at2.size(), 1u) << "the SDO request leaked to vcan2: " << can::to_string(at2[0]);

  cansend("vcan1", "582#4318100178563412");
  const Frame reply = Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 0x78, 0x56, 0x34, 0x12});
  auto at0 = until(vcan0_, reply);  // vcan0 also shows what cansend itself sent there
  EXPECT_EQ(at0.back(), reply);
}

TEST_F(Tunnel, NodeSpecificNmtIsRewrittenAndBroadcastReachesBoth) {
  cansend("vcan0", "000#0122");
  cansend("vcan0", "000#8000");
  const Frame marker = Frame::standard(0x000, {0x80, 0x00});
  auto at1 = until(vcan1_, marker);
  auto at2 = until(vcan2_, marker);
  ASSERT_EQ(at1.size(), 2u);
  EXPECT_EQ(at1[0], Frame::standard(0x000, {0x01, 0x02}));
  EXPECT_EQ(at2.size(), 1u);
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
  ChildProcess candump({"candump", "-L", "-n", "1", "vcan1"});
  // candump is ready once its socket is bound; a frame sent before that would be missed, so
  // repeat the request until candump reports it (bounded by the deadline).
  const auto deadline = std::chrono::steady_clock::now() + 10s;
  while (!candump.wait(50ms)) {
    ASSERT_LT(std::chrono::steady_clock::now(), deadline) << candump.output();
    cansend("vcan0", "23F#CAFE");  // RPDO1 of surface node 63 = module 1 node 31
  }
  EXPECT_NE(candump.output().find("vcan1 21F#CAFE"), std::string::npos) << candump.output();
}

}  // namespace
}  // namespace canbridge
