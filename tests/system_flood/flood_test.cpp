// A flood of hostile connections does not keep a real gateway out (issue 15): a surface on vcan0
// and a gateway on vcan1 run as real processes over TLS 1.3 PSK (keys made at run time); the
// gateway is killed and restarted, and the time until the surface has it bound again is measured
// with no flood, while canbridge-backbone-flood holds 1,100 idle connections, and while it runs at
// least 1,100 real TLS 1.3 handshakes with keys the surface does not know (the gateway's name with
// a wrong key, unknown names). Every one must be refused; the surface's RSS before and after the
// floods is compared, and its log stays a bounded number of lines under the floods.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <iostream>
#include <iterator>
#include <memory>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/process.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using test::ChildProcess;

constexpr auto kStep = 20s;        // upper bound of each awaited step on the slow rig
constexpr int kRestarts = 5;       // per condition; the median is compared
constexpr int kFloodPeers = 1100;  // the figure
constexpr const char* kFloodSource = "127.0.0.2";

// Resident set of a process in kB (VmRSS), -1 if unreadable.
long rss_kb(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  }
  return -1;
}

// CPU time (user + system) a process has used, in ms; -1 if unreadable.
long cpu_ms(pid_t pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string text((std::istreambuf_iterator<char>(stat)), std::istreambuf_iterator<char>());
  const auto after_name = text.rfind(')');  // the name may hold spaces
  if (after_name == std::string::npos) return -1;
  std::istringstream fields(text.substr(after_name + 2));
  std::string field;
  long utime = 0, stime = 0;
  for (int i = 3; i <= 15 && fields >> field; ++i) {
    if (i == 14) utime = std::stol(field);
    if (i == 15) stime = std::stol(field);
  }
  return (utime + stime) * 1000 / ::sysconf(_SC_CLK_TCK);
}

double median_ms(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? -1 : v[v.size() / 2];
}

class Flood : public ::testing::Test {
 protected:
  void SetUp() override {
    // The flood needs more than 1,100 descriptors; its child processes inherit the raised limit.
    rlimit limit{};
    ASSERT_EQ(::getrlimit(RLIMIT_NOFILE, &limit), 0);
    limit.rlim_cur = limit.rlim_max;
    ASSERT_EQ(::setrlimit(RLIMIT_NOFILE, &limit), 0);
    ASSERT_GE(limit.rlim_cur, rlim_t{kFloodPeers + 100})
        << "RLIMIT_NOFILE hard limit too low for the flood";
    std::cout << "[  flood   ] RLIMIT_NOFILE " << limit.rlim_cur << "\n";

    // The authenticated surface the issue asks about: TLS 1.3 with the gateway's pre-shared key.
    const std::string key = keys_.key("flood-gateway.key");
    const std::string surface_cfg = keys_.file(
        "flood-surface.yaml",
        "role: surface\nname: flood-surface\nbus: vcan0\nbackbone:\n  listen: 127.0.0.1:0\n"
        "  auth: {mode: psk}\n"
        "  admission: {max_pending_handshakes: 32, handshake_timeout_ms: 2000, max_links: 0}\n"
        "gateways: [{name: flood-gateway, modules: [1], key_file: " +
            key + "}]\nlog:\n  level: info\n");
    // CANBRIDGE_FLOOD_SURFACE_BIN runs another build's surface (the numbers before a change).
    const char* surface_bin = std::getenv("CANBRIDGE_FLOOD_SURFACE_BIN");
    surface_ = std::make_unique<ChildProcess>(std::vector<std::string>{
        surface_bin ? surface_bin : CANBRIDGE_BIN, "surface", "--config", surface_cfg});
    ASSERT_TRUE(surface_->wait_for_line("backbone: listening on 127.0.0.1:", kStep))
        << surface_->output();
    std::smatch port;
    const std::string out = surface_->output();
    ASSERT_TRUE(
        std::regex_search(out, port, std::regex("backbone: listening on 127\\.0\\.0\\.1:([0-9]+)")))
        << out;
    port_ = port[1].str();
    // max_links 0: 4 for the one configured gateway + 8.
    EXPECT_NE(out.find("admission: 32 pending handshakes, 2000 ms handshake timeout, 12 links"),
              std::string::npos)
        << out;
    const std::string gateway_head =
        "role: gateway\nname: flood-gateway\nbackbone:\n  connect: "
        "127.0.0.1:" +
        port_ + "\n  auth: {mode: psk, key_file: " + key + ", surface: flood-surface}\n";
    const std::string gateway_modules = "modules:\n  - id: 1\n    bus: vcan1\n";
    gateway_cfg_ = keys_.file("flood-gateway.yaml", gateway_head +
                                                        "  reconnect_min_ms: 20\n"
                                                        "  reconnect_max_ms: 200\n" +
                                                        gateway_modules);
    // The shipped reconnection back-off (100 ms doubling to 5 s): what a lock-out costs a real
    // gateway, each refused attempt making it wait longer.
    default_gateway_cfg_ =
        keys_.file("flood-gateway-defaults.yaml", gateway_head + gateway_modules);
    ASSERT_NO_FATAL_FAILURE(start_gateway());
  }

  void TearDown() override {
    if (flood_) flood_->stop();
    if (idle_flood_) idle_flood_->stop();
    if (gateway_) gateway_->stop();
    if (surface_) {
      EXPECT_EQ(surface_->stop(), 0);
      if (HasFailure() || std::getenv("CANBRIDGE_SHOW_LOGS")) {
        std::cout << "--- surface\n" << surface_->output();
        if (gateway_) std::cout << "--- gateway\n" << earlier_gateway_logs_ << gateway_->output();
        if (flood_) std::cout << "--- flood\n" << flood_->output();
        if (idle_flood_) std::cout << "--- idle flood\n" << test::last_line(idle_flood_->output());
      }
    }
  }

  // Starts the gateway; returns once the surface has bound it, with the reconnection time: from
  // the gateway's start line (printed once its client is connecting) to the surface's "ready"
  // line, both from the logs' clock. The process's own start-up (exec, linking, opening its bus)
  // is left out: on the rig's one CPU it varies by seconds with whatever else runs.
  double start_gateway() {
    const auto started = Clock::now();
    if (gateway_) earlier_gateway_logs_ += gateway_->output();
    gateway_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", gateway_cfg_});
    EXPECT_TRUE(surface_->wait_for_line("gateway 'flood-gateway' ready", kStep))
        << gateway_->output();
    EXPECT_TRUE(gateway_->wait_for_line("module(s), backbone tcp", kStep)) << gateway_->output();
    const long connecting = log_time_ms(gateway_->output(), "module(s), backbone tcp");
    long bound = log_time_ms(surface_->output(), "gateway 'flood-gateway' ready");
    long reconnection = bound - connecting;
    if (reconnection < -12 * 3600 * 1000L) reconnection += 24 * 3600 * 1000L;  // past midnight
    // A "ready" from before this start (the previous process bound twice, e.g. after losing its
    // link) matched: wait for this process's own.
    while (reconnection < 0 && surface_->wait_for_line("gateway 'flood-gateway' ready", kStep)) {
      bound = log_time_ms(surface_->output(), "gateway 'flood-gateway' ready");
      reconnection = bound - connecting;
    }
    EXPECT_GE(reconnection, 0) << "the surface never bound the restarted gateway";
    const double total = std::chrono::duration<double, std::milli>(Clock::now() - started).count();
    std::cout << "[  flood   ]   process start to bound " << static_cast<long>(total)
              << " ms, reconnection " << reconnection << " ms\n";
    return static_cast<double>(reconnection);
  }

  // The time of day in ms of the last log line containing `needle` ("YYYY-MM-DD HH:MM:SS.mmm").
  static long log_time_ms(const std::string& log, const std::string& needle) {
    const auto at = log.rfind(needle);
    if (at == std::string::npos) return -1;
    const auto line_start = log.rfind('\n', at);
    const std::string line = log.substr(line_start == std::string::npos ? 0 : line_start + 1, 64);
    std::smatch m;
    if (!std::regex_search(line, m,
                           std::regex("^\\S+ ([0-9]{2}):([0-9]{2}):([0-9]{2})\\.([0-9]{3})"))) {
      ADD_FAILURE() << "no time stamp in: " << line;
      return -1;
    }
    return ((std::stol(m[1].str()) * 60 + std::stol(m[2].str())) * 60 + std::stol(m[3].str())) *
               1000 +
           std::stol(m[4].str());
  }

  // Kills the gateway (no goodbye: a cut) and starts it again, kRestarts times; the times from
  // each start until the surface had it bound again.
  std::vector<double> restarts(const std::string& condition) {
    std::vector<double> ms;
    for (int i = 0; i < kRestarts; ++i) {
      ::kill(gateway_->pid(), SIGKILL);
      EXPECT_TRUE(gateway_->wait(kStep).has_value());
      ms.push_back(start_gateway());
      if (::testing::Test::HasFailure()) break;
    }
    std::cout << "[  flood   ] " << condition << ": gateway bound again after";
    for (double m : ms) std::cout << " " << static_cast<long>(m) << " ms";
    std::cout << " (median " << static_cast<long>(median_ms(ms)) << " ms)\n";
    ::testing::Test::RecordProperty(condition + "_median_ms", static_cast<int>(median_ms(ms)));
    return ms;
  }

  void start_flood(std::vector<std::string> args) {
    // The flood stands for peers elsewhere on the network; here it shares the rig's one CPU, so
    // it runs at the lowest priority: it still takes every cycle the surface and gateway leave,
    // but what is measured is what admission does, not how the scheduler shares one CPU.
    flood_ = launch_flood(args, "19");
    // The first progress line: the flood has been running for a report interval.
    ASSERT_TRUE(flood_->wait_for_line("backbone-flood: progress", kStep)) << flood_->output();
  }

  // The flood at niceness `nice`. It connects from 127.0.0.2 (loopback too): the surface
  // throttles a source that keeps failing, and a flood from the gateway's own address could not
  // be told apart from the gateway.
  std::unique_ptr<ChildProcess> launch_flood(const std::vector<std::string>& args,
                                             const std::string& nice,
                                             const std::vector<std::string>& from = {}) const {
    std::vector<std::string> argv{
        "nice", "-n", nice, FLOOD_BIN, "--connect", "127.0.0.1:" + port_, "--bind", kFloodSource};
    argv.insert(argv.end(), from.begin(), from.end());
    argv.insert(argv.end(), args.begin(), args.end());
    return std::make_unique<ChildProcess>(argv);
  }

  // Stops the flood and returns its final line.
  std::string end_flood(const std::string& condition) {
    flood_->stop();
    const std::string last = test::last_line(flood_->output());
    std::cout << "[  flood   ] " << condition << ": " << last << "\n";
    EXPECT_NE(last.find("backbone-flood: done"), std::string::npos) << flood_->output();
    flood_.reset();
    return last;
  }

  // A counter `name=N` of the flood's last progress line; -1 if absent.
  static long flood_count(const std::string& line, const std::string& name) {
    std::smatch m;
    if (!std::regex_search(line, m, std::regex("\\b" + name + "=([0-9]+)"))) return -1;
    return std::stol(m[1].str());
  }

  // Waits (the flood keeps cycling) until the flood has run at least `n` handshakes.
  void await_handshakes(long n) {
    const auto until = Clock::now() + 3 * kStep;
    while (flood_count(test::last_line(flood_->output()), "handshakes") < n &&
           Clock::now() < until) {
      flood_->wait_for_line("backbone-flood: progress", 1s);  // the next report, at most 1 s
      if (flood_->finished()) break;
    }
  }

  // The surface's log lines from `from` (a length of its output) on, but the gateway's own
  // reconnections (bound, lost, ...: "flood-gateway" lines), which the restarts cause.
  std::vector<std::string> surface_lines_since(std::size_t from) const {
    std::vector<std::string> lines;
    std::istringstream in(surface_->output().substr(from));
    for (std::string line; std::getline(in, line);) {
      if (line.find("flood-gateway") == std::string::npos) lines.push_back(line);
    }
    return lines;
  }

  // The surface's RSS once it is back within `limit_kb` of `baseline_kb`, or the last value seen
  // after `within`: the surface frees pending connections at their handshake deadline.
  long settled_rss_kb(long baseline_kb, long limit_kb, std::chrono::milliseconds within) {
    const auto until = Clock::now() + within;
    long rss = rss_kb(surface_->pid());
    while (rss - baseline_kb > limit_kb && Clock::now() < until) {
      // Each restart is a full round trip through the surface: a natural pace for polling.
      start_gateway_after_kill();
      rss = rss_kb(surface_->pid());
    }
    return rss;
  }

  void start_gateway_after_kill() { start_gateway_after_kill_ms(); }

  // Kills the gateway and starts it again; its reconnection time (see start_gateway).
  double start_gateway_after_kill_ms() {
    ::kill(gateway_->pid(), SIGKILL);
    EXPECT_TRUE(gateway_->wait(kStep).has_value());
    return start_gateway();
  }

  // The seconds a flood has run, from its last progress line; -1 before the first.
  static double flood_elapsed_s(const ChildProcess& flood) {
    std::smatch m;
    const std::string line = test::last_line(flood.output());
    if (!std::regex_search(line, m, std::regex("elapsed_s=([0-9.]+)"))) return -1;
    return std::stod(m[1].str());
  }

  // How many lines of `log` contain `needle`.
  static long count_lines(const std::string& log, const std::string& needle) {
    long n = 0;
    for (auto at = log.find(needle); at != std::string::npos; at = log.find(needle, at + 1)) ++n;
    return n;
  }

  void failing_handshakes_neither_lock_out_a_gateway_nor_kill_its_link(std::size_t sources);

  test::TempKeyDir keys_;
  std::unique_ptr<ChildProcess> surface_, gateway_, flood_, idle_flood_;
  std::string port_, gateway_cfg_, default_gateway_cfg_;
  std::string earlier_gateway_logs_;  // of the gateway processes before the current one
};

TEST_F(Flood, FloodsDoNotDelayAGatewaysReconnectionNorKeepTheSurfacesMemory) {
  const double quiet = median_ms(restarts("no_flood"));
  const long rss_before = rss_kb(surface_->pid());
  std::cout << "[  flood   ] surface RSS before the floods: " << rss_before << " kB\n";

  const std::size_t log_before_floods = surface_->output().size();

  ASSERT_NO_FATAL_FAILURE(start_flood(
      {"--idle", std::to_string(kFloodPeers), "--duration", "120", "--report-ms", "500"}));
  const double idle = median_ms(restarts("idle_flood"));
  const long rss_during_idle = rss_kb(surface_->pid());
  end_flood("idle_flood");

  // Real TLS 1.3 handshakes, each with a key the surface does not know; cycling, so the flood
  // lasts through every restart, then runs on until it has done at least 1,100.
  ASSERT_NO_FATAL_FAILURE(
      start_flood({"--bad-handshakes", std::to_string(kFloodPeers), "--concurrency", "32", "--kind",
                   "psk", "--psk-name", "flood-gateway", "--linger-ms", "5000", "--cycle",
                   "--duration", "120", "--report-ms", "500"}));
  const double handshakes = median_ms(restarts("handshake_flood"));
  const long rss_during_handshakes = rss_kb(surface_->pid());
  await_handshakes(kFloodPeers);
  const std::string tls = end_flood("handshake_flood");
  const long done = flood_count(tls, "handshakes");
  const long refused = flood_count(tls, "tls_refused");
  const long accepted = flood_count(tls, "tls_accepted");
  std::cout << "[  flood   ] TLS handshakes with unknown keys: " << done << " done, " << refused
            << " refused, " << accepted << " accepted\n";
  RecordProperty("tls_handshakes_done", static_cast<int>(done));
  RecordProperty("tls_handshakes_refused", static_cast<int>(refused));
  EXPECT_GE(done, kFloodPeers);
  EXPECT_EQ(refused, done) << "every failing handshake must be refused by the surface";
  EXPECT_EQ(accepted, 0);
  // The surface counted them (one warning per reason, the rest counted): it saw them.
  EXPECT_NE(surface_->output().find("TLS handshake with"), std::string::npos);

  // Thousands of hostile connections: the surface warns once per kind of trouble, then counts.
  const auto flood_log = surface_lines_since(log_before_floods);
  std::cout << "[  flood   ] surface log during the floods: " << flood_log.size()
            << " line(s) (the gateway's own excluded)\n";
  RecordProperty("surface_flood_log_lines", static_cast<int>(flood_log.size()));
  EXPECT_LT(flood_log.size(), 30u) << [&] {
    std::string all;
    for (const auto& l : flood_log) all += l + "\n";
    return all;
  }();

  const long rss_after = settled_rss_kb(rss_before, 5 * 1024, 10s);
  std::cout << "[  flood   ] surface RSS: before " << rss_before << " kB, during idle flood "
            << rss_during_idle << " kB, during handshake flood " << rss_during_handshakes
            << " kB, after " << rss_after << " kB\n";
  RecordProperty("rss_before_kb", static_cast<int>(rss_before));
  RecordProperty("rss_after_kb", static_cast<int>(rss_after));

  EXPECT_LE(idle, quiet + 1000) << "the idle flood delayed the gateway";
  EXPECT_LE(handshakes, quiet + 1000) << "the handshake flood delayed the gateway";
  EXPECT_LE(rss_after - rss_before, 5 * 1024) << "the surface kept memory after the floods";
}

// Issue 27: 64 concurrent TLS-PSK handshakes with wrong keys, cycling, plus 1,100 idle
// connections, from `sources` other hosts (127.0.0.2 on). The gateway's link, established before
// the floods, must never be given up (dead or stale) while they run; a gateway restarted during
// them must be bound within kBindBound; and the surface's RSS must come back to within 2 MB of its
// level before the floods.
void Flood::failing_handshakes_neither_lock_out_a_gateway_nor_kill_its_link(std::size_t sources) {
  const std::vector<std::string> from{"--sources", std::to_string(sources)};
  // What a session logs when it gives a link up for silence, or because its own process did
  // not run for longer than the peer waits (session_core): either is a link lost to load.
  const std::vector<std::string> kLinkLost{"link dead, closing it", "stale ("};
  const auto links_lost = [&](const std::string& log) {
    long n = 0;
    for (const auto& needle : kLinkLost) n += count_lines(log, needle);
    return n;
  };
  // The bound, from the gateway's start line to the surface's "ready".
  constexpr double kBindBoundMs = 2000;
  constexpr double kFloodedLinkS = 8;  // four times the default dead_after_ms under the floods
  constexpr long kRssSlackKb = 2 * 1024;

  gateway_cfg_ = default_gateway_cfg_;
  const double quiet = start_gateway_after_kill_ms();
  const long rss_before = rss_kb(surface_->pid());
  const std::size_t surface_mark = surface_->output().size();
  const std::size_t gateway_mark = earlier_gateway_logs_.size() + gateway_->output().size();
  const long surface_cpu_before = cpu_ms(surface_->pid());
  const auto flood_started = Clock::now();

  // At the surface's own priority: niced, the flood gets too little of the rig's one CPU to
  // lock anyone out (main's surface passed every assertion with it at nice 19).
  idle_flood_ = launch_flood(
      {"--idle", std::to_string(kFloodPeers), "--duration", "120", "--report-ms", "500"}, "0",
      from);
  ASSERT_TRUE(idle_flood_->wait_for_line("backbone-flood: progress", kStep))
      << idle_flood_->output();
  flood_ = launch_flood({"--bad-handshakes", std::to_string(kFloodPeers), "--concurrency", "64",
                         "--kind", "psk", "--psk-name", "flood-gateway", "--linger-ms", "5000",
                         "--cycle", "--duration", "120", "--report-ms", "500"},
                        "0", from);
  // The established link under both floods: the handshake flood's own clock, not a sleep.
  while (flood_elapsed_s(*flood_) < kFloodedLinkS && !flood_->finished()) {
    ASSERT_TRUE(flood_->wait_for_line("backbone-flood: progress", kStep)) << flood_->output();
  }
  const long rss_during = rss_kb(surface_->pid());
  const long surface_cpu = cpu_ms(surface_->pid()) - surface_cpu_before;
  const auto flood_wall =
      std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - flood_started);
  const std::string under_flood = test::last_line(flood_->output());

  // Gateway restarts in the middle of the floods.
  std::vector<double> binds;
  for (int i = 0; i < 3 && !HasFailure(); ++i) {
    binds.push_back(start_gateway_after_kill_ms());
  }
  const std::string handshakes = end_flood("handshake_flood+idle_flood");
  idle_flood_->stop();
  std::cout << "[  flood   ] idle flood: " << test::last_line(idle_flood_->output()) << "\n";
  idle_flood_.reset();
  const long gateway_dead =
      links_lost((earlier_gateway_logs_ + gateway_->output()).substr(gateway_mark));
  const long surface_dead = links_lost(surface_->output().substr(surface_mark));

  const long rss_after = settled_rss_kb(rss_before, kRssSlackKb, 10s);
  const double worst = *std::max_element(binds.begin(), binds.end());
  std::cout << "[  flood   ] quiet bind " << static_cast<long>(quiet) << " ms; under the floods";
  for (double b : binds) std::cout << " " << static_cast<long>(b) << " ms";
  std::cout << "\n[  flood   ] links lost (dead or stale): surface " << surface_dead << ", gateway "
            << gateway_dead << "\n[  flood   ] surface RSS before " << rss_before << " kB, during "
            << rss_during << " kB, after " << rss_after << " kB\n[  flood   ] at " << kFloodedLinkS
            << " s: " << under_flood << "\n[  flood   ] surface CPU under the floods "
            << surface_cpu << " ms in " << flood_wall.count() << " ms\n";
  RecordProperty("worst_bind_ms", static_cast<int>(worst));
  RecordProperty("rss_before_kb", static_cast<int>(rss_before));
  RecordProperty("rss_during_kb", static_cast<int>(rss_during));
  RecordProperty("rss_after_kb", static_cast<int>(rss_after));

  EXPECT_EQ(flood_count(handshakes, "tls_accepted"), 0);
  EXPECT_GT(flood_count(handshakes, "handshakes"), 0);
  EXPECT_EQ(surface_dead, 0) << "the surface gave an established link up";
  EXPECT_EQ(gateway_dead, 0) << "the gateway gave an established link up";
  EXPECT_LE(worst, kBindBoundMs) << "the floods delayed the gateway's bind";
  EXPECT_LE(rss_after - rss_before, kRssSlackKb) << "the surface kept memory after the floods";
}

// From one host the source throttle (backbone/admission_source_throttle) is what keeps the flood
// out; main's surface (CANBRIDGE_FLOOD_SURFACE_BIN) fails this test.
TEST_F(Flood, FailingHandshakesFromOneHostNeitherLockOutAGatewayNorKillItsLink) {
  failing_handshakes_neither_lock_out_a_gateway_nor_kill_its_link(1);
}

// From 64 hosts, each within its own source budget at first: the per-source throttle alone no
// longer decides who keeps a pending slot.
TEST_F(Flood, FailingHandshakesFromManyHostsNeitherLockOutAGatewayNorKillItsLink) {
  failing_handshakes_neither_lock_out_a_gateway_nor_kill_its_link(64);
}

}  // namespace
}  // namespace canbridge
