// SIGHUP on a real `canbridge surface` (plain auth on loopback, vcan0) and a real `canbridge
// gateway` (module 1 on vcan0, its surface not there): the rewritten file's log.level and
// log.stats_interval_s apply at once and a changed `gateways` / `modules` section is named as
// needing a restart; an invalid file is reported and the role keeps running with what it has;
// SIGTERM still ends it with status 0.
#include <gtest/gtest.h>
#include <signal.h>

#include <chrono>
#include <fstream>
#include <string>

#include "tests/support/process.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using test::ChildProcess;

constexpr auto kStep = 20s;  // upper bound of each awaited step on the rig's one CPU

std::string surface_yaml(const std::string& level, int stats_interval_s,
                         const std::string& modules) {
  return "role: surface\nname: reload-surface\nbus: vcan0\nbackbone:\n  listen: 127.0.0.1:0\n"
         "  auth: {mode: plain}\ngateways: [{name: reload-gateway, modules: " +
         modules + "}]\nlog:\n  level: " + level +
         "\n  stats_interval_s: " + std::to_string(stats_interval_s) + "\n";
}

// A gateway whose surface is not there: it keeps reconnecting, which SIGHUP must not disturb.
std::string gateway_yaml(const std::string& level, int stats_interval_s, const std::string& bus) {
  return "role: gateway\nname: reload-gateway\nbackbone:\n  connect: 127.0.0.1:9\n"
         "  auth: {mode: plain}\nmodules:\n  - id: 1\n    bus: " +
         bus + "\nlog:\n  level: " + level +
         "\n  stats_interval_s: " + std::to_string(stats_interval_s) + "\n";
}

void write(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
  ASSERT_TRUE(out.good()) << path;
}

class Reload : public ::testing::Test {
 protected:
  void TearDown() override {
    if (HasFailure() || std::getenv("CANBRIDGE_SHOW_LOGS")) {
      std::cout << "--- surface\n" << (surface_ ? surface_->output() : std::string());
    }
  }
  std::string path_ = ::testing::TempDir() + "reload-surface.yaml";
  std::unique_ptr<ChildProcess> surface_;
};

TEST_F(Reload, SighupAppliesLogLevelAndStatsIntervalAndKeepsRunningOnAnInvalidFile) {
  ASSERT_NO_FATAL_FAILURE(write(path_, surface_yaml("info", 0, "[1]")));
  surface_ = std::make_unique<ChildProcess>(
      std::vector<std::string>{CANBRIDGE_BIN, "surface", "--config", path_});
  ASSERT_TRUE(surface_->wait_for_line("listening on 127.0.0.1:", kStep));
  // Statistics are off (0): no counter line until the reload turns them on.
  EXPECT_EQ(surface_->output().find("gateway(s) up"), std::string::npos);

  ASSERT_NO_FATAL_FAILURE(write(path_, surface_yaml("debug", 1, "[1, 2]")));
  ASSERT_EQ(::kill(surface_->pid(), SIGHUP), 0);
  ASSERT_TRUE(surface_->wait_for_line("config reloaded from " + path_ +
                                          ": log.level debug (was info), "
                                          "log.stats_interval_s 1 (was 0)",
                                      kStep));
  ASSERT_TRUE(surface_->wait_for_line("config reload: gateways changed: restart to apply", kStep));
  // The new interval runs: counter lines now come, once a second.
  ASSERT_TRUE(
      surface_->wait_for_line("surface reload-surface: 0/1 gateway(s) up; bus vcan0", kStep));
  EXPECT_FALSE(surface_->finished());

  // An invalid file: every problem logged, the running settings stay (the counters go on).
  ASSERT_NO_FATAL_FAILURE(write(path_, surface_yaml("loud", 1, "[1, 2]")));
  ASSERT_EQ(::kill(surface_->pid(), SIGHUP), 0);
  ASSERT_TRUE(surface_->wait_for_line(
      "config reload from " + path_ + " failed, keeping the running settings", kStep));
  ASSERT_TRUE(surface_->wait_for_line("log.level: 'loud' is not one of", kStep));
  ASSERT_TRUE(
      surface_->wait_for_line("surface reload-surface: 0/1 gateway(s) up; bus vcan0", kStep));
  EXPECT_FALSE(surface_->finished());

  EXPECT_EQ(surface_->stop(), 0);
}

TEST_F(Reload, ACommandLineLevelIsNotOverriddenByTheFile) {
  ASSERT_NO_FATAL_FAILURE(write(path_, surface_yaml("info", 0, "[1]")));
  surface_ = std::make_unique<ChildProcess>(
      std::vector<std::string>{CANBRIDGE_BIN, "surface", "-c", path_, "--log-level", "info"});
  ASSERT_TRUE(surface_->wait_for_line("listening on 127.0.0.1:", kStep));
  ASSERT_NO_FATAL_FAILURE(write(path_, surface_yaml("error", 0, "[1]")));
  ASSERT_EQ(::kill(surface_->pid(), SIGHUP), 0);
  ASSERT_TRUE(surface_->wait_for_line(
      "nothing to apply (log.level info, log.stats_interval_s 0); log.level error not applied: "
      "the command line set info",
      kStep));
  ASSERT_TRUE(surface_->wait_for_line(
      "config reload: no other setting changed (nothing needs a restart)", kStep));
  EXPECT_EQ(surface_->stop(), 0);
}

TEST_F(Reload, GatewaySighupAppliesLogSettingsNamesModulesAndSurvivesAnInvalidFile) {
  const std::string path = ::testing::TempDir() + "reload-gateway.yaml";
  ASSERT_NO_FATAL_FAILURE(write(path, gateway_yaml("info", 0, "vcan0")));
  surface_ = std::make_unique<ChildProcess>(
      std::vector<std::string>{CANBRIDGE_BIN, "gateway", "--config", path});
  ASSERT_TRUE(surface_->wait_for_line("cannot connect to 127.0.0.1:9", kStep));
  EXPECT_EQ(surface_->output().find("gateway reload-gateway: link"), std::string::npos);

  // The module's bus changes too: a restart is needed for that, and the log says so.
  ASSERT_NO_FATAL_FAILURE(write(path, gateway_yaml("debug", 1, "vcan1")));
  ASSERT_EQ(::kill(surface_->pid(), SIGHUP), 0);
  ASSERT_TRUE(surface_->wait_for_line("config reloaded from " + path +
                                          ": log.level debug (was info), "
                                          "log.stats_interval_s 1 (was 0)",
                                      kStep));
  ASSERT_TRUE(surface_->wait_for_line("config reload: modules changed: restart to apply", kStep));
  ASSERT_TRUE(surface_->wait_for_line("gateway reload-gateway: link", kStep));
  EXPECT_FALSE(surface_->finished());

  ASSERT_NO_FATAL_FAILURE(write(path, "role: gateway\nname: [unclosed\n"));
  ASSERT_EQ(::kill(surface_->pid(), SIGHUP), 0);
  ASSERT_TRUE(surface_->wait_for_line(
      "config reload from " + path + " failed, keeping the running settings", kStep));
  EXPECT_FALSE(surface_->finished());
  EXPECT_EQ(surface_->stop(), 0);
}

}  // namespace
}  // namespace canbridge
