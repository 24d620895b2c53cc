// The serial backbone's authentication against an attacker on the line: the real surface (vcan0)
// and gateway (vcan1) with `auth: psk`, their pty line through serial-tamper-proxy, which on
// command flips a byte inside a frame (CRC recomputed), cuts a frame short (valid CRC) and
// re-sends an earlier frame. The surface must reject each by reason (its counter line), put
// nothing of them on vcan0, and the tunnel must carry every frame exactly once, in order.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <cerrno>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <regex>
#include <system_error>

#include "can/candump_log.hpp"
#include "tests/support/process.hpp"
#include "tests/support/raw_can.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::ChildProcess;
using test::RawCanSocket;

constexpr auto kEvent = 20s;

std::string make_temp_dir() {
  std::string path = ::testing::TempDir() + "serial_auth.XXXXXX";
  if (::mkdtemp(path.data()) == nullptr) {
    throw std::system_error(errno, std::system_category(), "mkdtemp " + path);
  }
  return path;
}

void write_file(const std::string& path, const std::string& text, mode_t mode = 0644) {
  std::ofstream(path) << text;
  ::chmod(path.c_str(), mode);
}

// The numbers after "rejected truncated/bad-tag/replay " in a counter line.
struct Rejected {
  long long truncated = -1, bad_tag = -1, replay = -1;
};
Rejected rejected(const std::string& line) {
  std::smatch m;
  Rejected r;
  if (std::regex_search(
          line, m, std::regex("rejected truncated/bad-tag/replay ([0-9]+)/([0-9]+)/([0-9]+)"))) {
    r = {std::stoll(m[1]), std::stoll(m[2]), std::stoll(m[3])};
  }
  return r;
}

// An SDO upload response of module 1's node 2 carrying `i`, and how the surface shows it (node
// 34: 0x5A2).
Frame response(int i) {
  const auto b = static_cast<std::uint8_t>(i);
  return Frame::standard(0x582, {0x43, 0x00, 0x20, 0x01, b, static_cast<std::uint8_t>(~b), 1, 2});
}
Frame on_surface(Frame f) {
  f.id += 0x20;
  return f;
}

class SerialAuth : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = make_temp_dir();
    const std::string gw_tty = dir_ + "/gw", surface_tty = dir_ + "/surface";
    commands_ = dir_ + "/commands";
    proxy_ = std::make_unique<ChildProcess>(std::vector<std::string>{
        SERIAL_TAMPER_PROXY_BIN, "--a", gw_tty, "--b", surface_tty, "--commands", commands_});
    ASSERT_TRUE(proxy_->wait_for_line("serial-tamper-proxy: ready", kEvent)) << proxy_->output();

    const std::string key = dir_ + "/serial-gateway.key";
    write_file(key, "# test key\n" + std::string(64, 'a') + "\n", 0600);
    const std::string tuning =
        "  keepalive_ms: 200\n  dead_after_ms: 1000\n  retransmit_ms: 1000\n"
        "  max_write_bytes: 512\n";
    const std::string log = "log:\n  level: info\n  stats_interval_s: 0\n";
    write_file(dir_ + "/surface.yaml",
               "role: surface\nname: serial-surface\nbus: vcan0\nbackbone:\n"
               "  auth:\n    mode: psk\n"
               "  serial:\n    - {device: " +
                   surface_tty + ", baud: 115200, gateway: serial-gateway}\n" + tuning +
                   "gateways:\n  - name: serial-gateway\n    modules: [1]\n    key_file: " + key +
                   "\n" + log);
    write_file(dir_ + "/gateway.yaml",
               "role: gateway\nname: serial-gateway\nbackbone:\n"
               "  auth:\n    mode: psk\n    key_file: " +
                   key + "\n    surface: serial-surface\n" + "  serial: {device: " + gw_tty +
                   ", baud: 115200}\n  reconnect_min_ms: 100\n" + tuning +
                   "modules:\n  - id: 1\n    bus: vcan1\n" + log);
    surface_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "surface", "--config", dir_ + "/surface.yaml"});
    gateway_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", dir_ + "/gateway.yaml"});
    ASSERT_TRUE(surface_->wait_for_line("proved to be 'serial-gateway'", kEvent))
        << surface_->output() << gateway_->output();
    ASSERT_TRUE(surface_->wait_for_line("ready over " + surface_tty, kEvent))
        << surface_->output() << gateway_->output();
  }

  void TearDown() override {
    std::string logs;
    for (auto* p : {&gateway_, &surface_, &proxy_}) {
      if (*p) {
        (*p)->stop();
        logs += (*p)->output();
      }
    }
    if (HasFailure()) std::cout << logs;
    std::filesystem::remove_all(dir_);
  }

  void command(const std::string& what) { std::ofstream(commands_) << what << "\n" << std::flush; }

  std::string dir_, commands_;
  std::unique_ptr<ChildProcess> proxy_, surface_, gateway_;
};

TEST_F(SerialAuth, TamperedTruncatedAndReplayedFramesAreRejectedCountedAndNeverReachTheBus) {
  RawCanSocket vcan0("vcan0"), vcan1("vcan1");
  std::vector<Frame> expected;
  int next = 0;
  // Each attack hits the next data frame: send frames until the proxy reports it done.
  const std::vector<std::pair<std::string, std::string>> attacks = {
      {"tamper", "tampered"}, {"truncate", "truncated"}, {"replay", "replayed"}};
  for (std::size_t a = 0; a < attacks.size(); ++a) {
    command(attacks[a].first);
    bool done = false;
    for (int i = 0; i < 40 && !done; ++i) {
      vcan1.send(response(next));
      expected.push_back(on_surface(response(next)));
      ++next;
      done = proxy_->wait_for_line("(attack " + std::to_string(a + 1) + ")", 100ms);
    }
    ASSERT_TRUE(done) << attacks[a].second << " never happened: " << proxy_->output();
  }
  // The tunnel still carries frames afterwards; the marker comes last.
  const Frame marker = Frame::standard(0x582, {0x80, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF});
  for (int i = 0; i < 5; ++i, ++next) {
    vcan1.send(response(next));
    expected.push_back(on_surface(response(next)));
  }
  vcan1.send(marker);
  expected.push_back(on_surface(marker));
  const auto seen = test::receive_until(vcan0, on_surface(marker), kEvent);
  ASSERT_TRUE(seen.marker_seen) << surface_->output();
  // Exactly what was sent, each once, in order: nothing tampered, cut or replayed on the bus.
  ASSERT_EQ(seen.frames.size(), expected.size());
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(seen.frames[i], expected[i]) << i << ": " << can::to_string(seen.frames[i]);
  }

  ASSERT_EQ(surface_->stop(), 0) << surface_->output();
  const std::string final_line = test::last_line(surface_->output());
  const Rejected r = rejected(final_line);
  // One of each, by reason; and the link was never restarted (still the first handshake).
  EXPECT_EQ(r.bad_tag, 1) << final_line;
  EXPECT_EQ(r.truncated, 1) << final_line;
  EXPECT_EQ(r.replay, 1) << final_line;
  EXPECT_NE(final_line.find("auth ok 1 "), std::string::npos) << final_line;
  const auto from = final_line.find("auth ok");
  std::cout << "[  rig     ] surface: "
            << final_line.substr(from, final_line.find(';', from) - from) << "\n";
}

}  // namespace
}  // namespace canbridge
