// Statistics of real processes (issue 18): a gateway on vcan1 + vcan2 and a surface on vcan0, each
// with its stats endpoint and Prometheus endpoint. Known traffic from cangen must show in
// `canbridge stats` as exact totals and as rates close to what the test measured itself; taking
// vcan1 down must be logged at once and show as "down", and frames must flow again once it is up;
// a surface killed and started again must count the gateway's nodes again.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <iostream>
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
using Clock = std::chrono::steady_clock;

// In a directory of this process's own: the rig's guests share the host's /tmp, and tests that
// run at the same time must not read each other's configs.
std::string write_file(const std::string& name, const std::string& text) {
  static test::TempKeyDir dir;
  return dir.file(name, text, 0644);
}

// The integer after `"key":` in the object that follows `anchor` (e.g. a bus's interface);
// -1 when missing. Enough JSON for a test: the document is canbridge's own, one line.
long long number_after(const std::string& json, const std::string& anchor, const std::string& key) {
  const std::size_t from = anchor.empty() ? 0 : json.find(anchor);
  if (from == std::string::npos) return -1;
  const std::string needle = "\"" + key + "\":";
  const std::size_t at = json.find(needle, from);
  if (at == std::string::npos) return -1;
  return std::stoll(json.substr(at + needle.size()));
}
double real_after(const std::string& json, const std::string& anchor, const std::string& key) {
  const std::size_t from = anchor.empty() ? 0 : json.find(anchor);
  const std::string needle = "\"" + key + "\":";
  const std::size_t at = json.find(needle, from);
  if (from == std::string::npos || at == std::string::npos) return -1;
  return std::stod(json.substr(at + needle.size()));
}

// `canbridge stats --endpoint PATH`: its one JSON line.
std::string stats(const std::string& endpoint) {
  const auto r = test::run({CANBRIDGE_BIN, "stats", "--endpoint", endpoint}, 10s,
                           test::Capture::stdout_and_stderr);
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(r.output.rfind("{\"role\":", 0), 0u) << r.output;
  return r.output;
}

// `canbridge stats` read again until `done` holds for it or `timeout` passes; the last reading.
template <typename Predicate>
std::string stats_until(const std::string& endpoint, std::chrono::milliseconds timeout,
                        Predicate done) {
  const auto deadline = Clock::now() + timeout;
  std::string json = stats(endpoint);
  while (!done(json) && Clock::now() < deadline) json = stats(endpoint);
  return json;
}

// GET /metrics on 127.0.0.1:`port` with a plain socket; the whole response.
std::string http_get(std::uint16_t port, const std::string& target) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::string response;
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) == 0) {
    const std::string request =
        "GET " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
    if (::send(fd, request.data(), request.size(), MSG_NOSIGNAL) ==
        static_cast<ssize_t>(request.size())) {
      char buffer[4096];
      for (ssize_t n; (n = ::recv(fd, buffer, sizeof buffer, 0)) > 0;) {
        response.append(buffer, static_cast<std::size_t>(n));
      }
    }
  }
  ::close(fd);
  return response;
}

std::uint16_t logged_port(const ChildProcess& p, const std::string& before) {
  std::smatch m;
  const std::string out = p.output();
  if (!std::regex_search(out, m, std::regex(before + "([0-9]+)"))) return 0;
  return static_cast<std::uint16_t>(std::stoul(m[1].str()));
}

class Statistics : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = ::testing::TempDir();
    surface_socket_ = dir_ + "stats-surface.sock";
    gateway_socket_ = dir_ + "stats-gateway.sock";
    start_surface("127.0.0.1:0");
    ASSERT_TRUE(surface_->wait_for_line("listening on 127.0.0.1:", 10s)) << surface_->output();
    const std::uint16_t backbone = logged_port(*surface_, "listening on 127\\.0\\.0\\.1:");
    surface_metrics_ = logged_port(*surface_, "metrics: serving http://127\\.0\\.0\\.1:");
    ASSERT_NE(backbone, 0) << surface_->output();
    ASSERT_NE(surface_metrics_, 0) << surface_->output();
    // Module 1 does not conflate: every one of cangen's PDOs must cross, for exact totals.
    const std::string gateway_cfg = write_file(
        "stats-gateway.yaml",
        "role: gateway\nname: stats-gateway\nbackbone:\n  connect: 127.0.0.1:" +
            std::to_string(backbone) +
            "\n  auth: {mode: plain}\n  reconnect_min_ms: 20\nmodules:\n  - id: 1\n    bus: vcan1\n"
            "    conflate_pdos: false\n  - id: 2\n    bus: vcan2\nstats_endpoint: " +
            gateway_socket_ +
            "\nmetrics: {listen: 127.0.0.1:0}\nlog:\n  level: info\n  stats_interval_s: 1\n");
    gateway_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", gateway_cfg});
    ASSERT_TRUE(surface_->wait_for_line("gateway 'stats-gateway' ready", 10s))
        << surface_->output() << gateway_->output();
    ASSERT_TRUE(gateway_->wait_for_line("surface 'stats-surface' ready", 10s))
        << gateway_->output();
    gateway_metrics_ = logged_port(*gateway_, "metrics: serving http://127\\.0\\.0\\.1:");
    ASSERT_NE(gateway_metrics_, 0) << gateway_->output();
    ready_ = true;
  }

  // Starts the surface with its backbone listening on `listen` (an ephemeral port at first, the
  // same port again after a restart, where the gateway reconnects).
  static void start_surface(const std::string& listen) {
    const std::string config = write_file(
        "stats-surface.yaml",
        "role: surface\nname: stats-surface\nbus: vcan0\nbackbone:\n  listen: " + listen +
            "\n  auth: {mode: plain}\n"
            "gateways: [{name: stats-gateway, modules: [1, 2]}]\n"
            "command_endpoint: {unix_socket: " +
            surface_socket_ +
            "}\nmetrics: {listen: 127.0.0.1:0}\nlog:\n  level: info\n"
            "  stats_interval_s: 1\n");
    surface_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "surface", "--config", config});
  }

  static void TearDownTestSuite() {
    if (gateway_) {
      EXPECT_EQ(gateway_->stop(), 0) << gateway_->output();
    }
    if (surface_) {
      EXPECT_EQ(surface_->stop(), 0) << surface_->output();
    }
    if (::testing::Test::HasFailure() || std::getenv("CANBRIDGE_SHOW_LOGS")) {
      if (gateway_) std::cout << "--- gateway\n" << gateway_->output();
      if (surface_) std::cout << "--- surface\n" << surface_->output();
    }
    gateway_.reset();
    surface_.reset();
  }

  void SetUp() override {
    ASSERT_TRUE(ready_) << "the surface and gateway did not start";
    ASSERT_FALSE(surface_->finished()) << surface_->output();
    ASSERT_FALSE(gateway_->finished()) << gateway_->output();
  }

  static inline std::unique_ptr<ChildProcess> surface_, gateway_;
  static inline std::string dir_, surface_socket_, gateway_socket_;
  static inline std::uint16_t surface_metrics_ = 0, gateway_metrics_ = 0;
  static inline bool ready_ = false;
};

constexpr const char* kVcan1 = "\"interface\":\"vcan1\"";
constexpr const char* kVcan0 = "\"interface\":\"vcan0\"";
constexpr const char* kBackbone = "\"backbone\":";

TEST_F(Statistics, KnownTrafficGivesExactTotalsAndMeasuredRates) {
  const std::string g0 = stats(gateway_socket_);
  const std::string s0 = stats(surface_socket_);
  const long long rx0 = number_after(g0, kVcan1, "rx_frames");
  const long long sent0 = number_after(g0, kBackbone, "frames_sent");
  const long long received0 = number_after(s0, kBackbone, "frames_received");
  const long long tx0 = number_after(s0, kVcan0, "tx_frames");
  const long long drops0 = number_after(g0, "\"drops\":", "total");
  ASSERT_GE(rx0, 0) << g0;
  ASSERT_GE(tx0, 0) << s0;

  // 2000 TPDO1 frames of module 1 node 1 (0x181), 2 ms apart: at most 500 frames/s.
  constexpr long long kFrames = 2000;
  const auto started = Clock::now();
  ChildProcess cangen({"cangen", "vcan1", "-g", "2", "-n", std::to_string(kFrames), "-I", "181",
                       "-L", "8", "-D", "i"});
  // One stats read well inside the run: once 1200 frames are counted, the gateway's last
  // one-second sampling window lies inside it (1200 frames took over 2 s at <= 500 frames/s,
  // and 800 more are to come).
  const auto counted_1200 = [&](const std::string& json) {
    return number_after(json, kVcan1, "rx_frames") - rx0 >= 1200;
  };
  const std::string first = stats_until(gateway_socket_, 60s, counted_1200);
  ASSERT_TRUE(counted_1200(first)) << "the traffic never reached 1200 frames\n"
                                   << gateway_->output();
  // And the next window (800 frames, over 1.6 s, are still to come): on a loaded machine one
  // window may catch cangen or the gateway descheduled for part of it (the gateway once reported
  // 185 frames/s in a run that averaged 331), so the rate is checked in whichever of two
  // consecutive windows shows it; a rate computed wrongly is wrong in both.
  const auto first_at = Clock::now();
  const std::string second = stats_until(
      gateway_socket_, 60s, [&](const std::string&) { return Clock::now() - first_at >= 1050ms; });
  ASSERT_EQ(cangen.wait(60s), 0) << cangen.output();
  // cangen's pace is steady, so its average over the run is the rate any window inside shows.
  const double measured =
      static_cast<double>(kFrames) / std::chrono::duration<double>(Clock::now() - started).count();
  const auto closer = [&](const std::string& a, const std::string& b, const char* key) {
    return std::abs(real_after(a, kVcan1, key) - measured) <=
                   std::abs(real_after(b, kVcan1, key) - measured)
               ? a
               : b;
  };
  const std::string during = closer(first, second, "rx_frames_per_s");
  const double reported = real_after(during, kVcan1, "rx_frames_per_s");
  std::cout << "[  rates   ] cangen averaged " << measured << " frames/s; the gateway reports "
            << reported << " (vcan1 rx), backbone "
            << real_after(during, kBackbone, "frames_sent_per_s") << " frames/s, "
            << real_after(during, kBackbone, "tx_bytes_per_s") << " B/s\n";
  EXPECT_GT(measured, 50.0);
  EXPECT_NEAR(reported, measured, measured * 0.4) << during;
  EXPECT_NEAR(real_after(during, kBackbone, "frames_sent_per_s"), measured, measured * 0.4)
      << during;
  EXPECT_GT(real_after(during, kBackbone, "tx_bytes_per_s"), 0.0) << during;

  // Totals: wait (by reading) until the surface wrote all of them, then every count is exact.
  stats_until(surface_socket_, 60s, [&](const std::string& json) {
    return number_after(json, kVcan0, "tx_frames") - tx0 >= kFrames;
  });
  const std::string g1 = stats(gateway_socket_);
  const std::string s1 = stats(surface_socket_);
  EXPECT_EQ(number_after(g1, kVcan1, "rx_frames") - rx0, kFrames) << g1;
  EXPECT_EQ(number_after(g1, kBackbone, "frames_sent") - sent0, kFrames) << g1;
  EXPECT_EQ(number_after(s1, kBackbone, "frames_received") - received0, kFrames) << s1;
  EXPECT_EQ(number_after(s1, kVcan0, "tx_frames") - tx0, kFrames) << s1;
  EXPECT_EQ(number_after(g1, "\"drops\":", "total"), drops0) << g1;
  EXPECT_EQ(number_after(g1, kVcan1, "rx_dropped_kernel"), 0) << g1;
  std::cout << "[  sample  ] canbridge stats (gateway): " << g1
            << "[  sample  ] canbridge stats (surface): " << s1;

  // Prometheus: the same totals, and 404 for anything else.
  const std::string metrics = http_get(gateway_metrics_, "/metrics");
  EXPECT_EQ(metrics.rfind("HTTP/1.1 200 OK", 0), 0u) << metrics;
  EXPECT_NE(
      metrics.find("canbridge_bus_frames_total{module=\"1\",bus=\"vcan1\",direction=\"rx\"} " +
                   std::to_string(rx0 + kFrames) + "\n"),
      std::string::npos)
      << metrics;
  EXPECT_NE(metrics.find("canbridge_bus_up{module=\"1\",bus=\"vcan1\"} 1\n"), std::string::npos)
      << metrics;
  const std::string surface_metrics = http_get(surface_metrics_, "/metrics");
  EXPECT_NE(surface_metrics.find("canbridge_bus_frames_total{module=\"0\",bus=\"vcan0\","
                                 "direction=\"tx\"} " +
                                 std::to_string(tx0 + kFrames) + "\n"),
            std::string::npos)
      << surface_metrics;
  EXPECT_EQ(http_get(gateway_metrics_, "/").rfind("HTTP/1.1 404", 0), 0u);
}

TEST_F(Statistics, InterfaceDownAndUpIsLoggedShownAndFramesFlowAgain) {
  RawCanSocket vcan0("vcan0");
  RawCanSocket vcan1("vcan1");  // stays bound across down/up (it skips the one ENETDOWN)
  ASSERT_EQ(test::run({"ip", "link", "set", "vcan1", "down"}).status, 0);
  ASSERT_TRUE(gateway_->wait_for_line("gateway stats-gateway: module 1 bus vcan1: down", 10s))
      << gateway_->output();
  const std::string down = stats(gateway_socket_);
  EXPECT_NE(down.find(std::string(kVcan1) + ",\"state\":\"down\",\"link_up\":false"),
            std::string::npos)
      << down;
  // A frame for module 1 while its interface is down: the SDO request waits in the bus's queue.
  const Frame request = Frame::standard(0x622, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  vcan0.send(request);
  ASSERT_EQ(test::run({"ip", "link", "set", "vcan1", "up"}).status, 0);
  ASSERT_TRUE(gateway_->wait_for_line("gateway stats-gateway: module 1 bus vcan1: up", 10s))
      << gateway_->output();
  // The request queued meanwhile reaches the bus (module 1 node 2: 0x602) ...
  const Frame local = Frame::standard(0x602, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  const auto at1 = test::receive_until(vcan1, local, 5000ms);
  EXPECT_TRUE(at1.marker_seen) << "the request queued while vcan1 was down never arrived";
  // ... and frames flow from the bus again: module 1 node 2's answer reaches vcan0 (0x5A2).
  vcan1.send(Frame::standard(0x582, {0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4}));
  EXPECT_TRUE(test::receive_until(
                  vcan0, Frame::standard(0x5A2, {0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4}), 5000ms)
                  .marker_seen)
      << "no frame from vcan1 reached vcan0 after it came up\n"
      << gateway_->output();
  const std::string up = stats(gateway_socket_);
  EXPECT_NE(up.find(std::string(kVcan1) + ",\"state\":\"error-active\",\"link_up\":true"),
            std::string::npos)
      << up;
  EXPECT_GE(number_after(up, kVcan1, "reopens"), 1) << up;
}

// The surface's node summary comes from the gateways' node events; a surface that was killed and
// started again has missed them all, so the gateway sends it a snapshot of its node table. The
// node below beats on and never changes state, so after the restart nothing but the snapshot can
// bring it back into the surface's statistics.
TEST_F(Statistics, ARestartedSurfaceCountsTheGatewaysNodesAgain) {
  // Module 1 node 5: boot-up, then an operational heartbeat every 100 ms (kept alive throughout).
  RawCanSocket vcan1("vcan1");
  vcan1.send(Frame::standard(0x705, {0x00}));
  ChildProcess heartbeats({"cangen", "vcan1", "-g", "100", "-I", "705", "-L", "1", "-D", "05"});
  const auto operational_nodes = [](const std::string& json) {
    return number_after(json, "\"nodes\":", "operational");
  };
  const std::string before = stats_until(
      surface_socket_, 10s, [&](const std::string& json) { return operational_nodes(json) >= 1; });
  ASSERT_GE(operational_nodes(before), 1) << before << gateway_->output();
  const long long total = number_after(before, "\"nodes\":", "total");

  // SIGKILL: nothing is flushed or said goodbye; then the same config (the gateway reconnects to
  // the same port).
  const std::uint16_t backbone = logged_port(*surface_, "listening on 127\\.0\\.0\\.1:");
  ASSERT_EQ(::kill(surface_->pid(), SIGKILL), 0);
  ASSERT_TRUE(surface_->wait(10s).has_value());
  start_surface("127.0.0.1:" + std::to_string(backbone));
  ASSERT_TRUE(surface_->wait_for_line("gateway 'stats-gateway' ready", 20s))
      << surface_->output() << gateway_->output();

  const std::string after = stats_until(surface_socket_, 10s, [&](const std::string& json) {
    return operational_nodes(json) >= operational_nodes(before);
  });
  EXPECT_EQ(number_after(after, "\"nodes\":", "total"), total) << after;
  EXPECT_EQ(operational_nodes(after), operational_nodes(before)) << after;
  EXPECT_EQ(number_after(after, "\"nodes\":", "lost"), number_after(before, "\"nodes\":", "lost"))
      << after;
  // The node beat on throughout (cangen exits 1 on SIGTERM: its status says nothing here).
  EXPECT_FALSE(heartbeats.finished()) << heartbeats.output();
  heartbeats.stop();
}

}  // namespace
}  // namespace canbridge
