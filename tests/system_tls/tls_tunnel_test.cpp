// A TCP backbone over TLS 1.3 PSK between real canbridge processes on vcan: a gateway with the
// wrong key is refused at the handshake and nothing it reads off its module bus reaches the
// surface bus; a gateway with the right key then carries frames across. Keys are made here.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <regex>

#include "tests/support/process.hpp"
#include "tests/support/raw_can.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::ChildProcess;
using test::RawCanSocket;

class TlsTunnel : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::path(::testing::TempDir()) /
           ("canbridge_tls_rig_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    for (const char* name : {"right", "wrong"}) {
      const auto r = test::run({"sh", "-c",
                                "umask 077 && openssl rand -hex 32 > '" +
                                    (dir_ / (std::string(name) + ".key")).string() + "'"});
      ASSERT_EQ(r.status, 0) << r.output;
    }
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string write(const std::string& name, const std::string& text) {
    const auto path = (dir_ / name).string();
    std::ofstream(path) << text;
    return path;
  }
  std::string key(const std::string& name) { return (dir_ / (name + ".key")).string(); }

  // A gateway for module 1 on vcan1 proving with key `key_name`.
  std::unique_ptr<ChildProcess> gateway(const std::string& port, const std::string& key_name) {
    const std::string config =
        write("gateway-" + key_name + ".yaml",
              "role: gateway\nname: tls-gw\nbackbone:\n  connect: 127.0.0.1:" + port +
                  "\n  auth: {mode: psk, key_file: " + key(key_name) +
                  ", surface: tls-surface}\n  reconnect_min_ms: 20\n  reconnect_max_ms: 200\n"
                  "modules:\n  - {id: 1, bus: vcan1}\n");
    return std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", config});
  }

  std::filesystem::path dir_;
};

TEST_F(TlsTunnel, WrongKeyIsRefusedAndSilentOnTheSurfaceBusThenTheRightKeyCrosses) {
  const std::string surface_config =
      write("surface.yaml",
            "role: surface\nname: tls-surface\nbus: vcan0\nbackbone:\n  listen: "
            "127.0.0.1:0\n  auth: {mode: psk}\n"
            "gateways: [{name: tls-gw, modules: [1], key_file: " +
                key("right") + "}]\n");
  ChildProcess surface({CANBRIDGE_BIN, "surface", "--config", surface_config});
  ASSERT_TRUE(surface.wait_for_line("listening on 127.0.0.1:", 10s)) << surface.output();
  std::smatch port;
  const std::string started = surface.output();
  ASSERT_TRUE(
      std::regex_search(started, port, std::regex("listening on 127\\.0\\.0\\.1:([0-9]+)")));

  // Module 1's node 1 TPDO1 (0x181) appears on the surface bus as node 33's (0x1A1).
  RawCanSocket surface_bus("vcan0", {0x181, 0x1A1});

  auto impostor = gateway(port[1].str(), "wrong");
  ASSERT_TRUE(surface.wait_for_line("TLS handshake", 10s)) << surface.output();
  ASSERT_TRUE(impostor->wait_for_line("cannot connect to", 10s)) << impostor->output();
  const auto burst = test::run({"cangen", "vcan1", "-g", "2", "-n", "200", "-I", "181", "-L", "8"});
  ASSERT_EQ(burst.status, 0) << burst.output;
  // The burst has left vcan1; anything forwarded would arrive within this bounded window.
  const auto leaked = surface_bus.receive(1000ms);
  EXPECT_FALSE(leaked) << "a frame of the refused gateway reached the surface bus: "
                       << can::to_string(*leaked);
  EXPECT_EQ(surface.output().find("gateway 'tls-gw' ready"), std::string::npos) << surface.output();
  EXPECT_NE(surface.output().find("unknown_identity"), std::string::npos) << surface.output();
  EXPECT_EQ(impostor->stop(), 0) << impostor->output();

  auto real = gateway(port[1].str(), "right");
  ASSERT_TRUE(surface.wait_for_line("gateway 'tls-gw' ready", 10s))
      << surface.output() << real->output();
  ASSERT_TRUE(real->wait_for_line("surface 'tls-surface' ready", 10s)) << real->output();
  const auto frames =
      test::run({"cangen", "vcan1", "-g", "1", "-n", "20", "-I", "181", "-L", "8", "-D", "i"});
  ASSERT_EQ(frames.status, 0) << frames.output;
  // Process data may be conflated on the way (same COB-ID, newer value wins), so what must
  // arrive is at least one frame and the last value (cangen -D i counts 0..19 in byte 0).
  int crossed = 0;
  bool last_seen = false;
  while (auto f = surface_bus.receive(3000ms)) {
    EXPECT_EQ(f->id, 0x1A1u) << can::to_string(*f);
    ++crossed;
    if (f->len > 0 && f->data[0] == 19) {
      last_seen = true;
      break;
    }
  }
  EXPECT_GE(crossed, 1);
  EXPECT_TRUE(last_seen) << crossed << " frame(s) crossed\n" << surface.output() << real->output();
  EXPECT_EQ(real->stop(), 0) << real->output();
  EXPECT_EQ(surface.stop(), 0) << surface.output();
}

}  // namespace
}  // namespace canbridge
