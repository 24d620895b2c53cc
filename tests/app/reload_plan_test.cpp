#include "app/reload_plan.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

constexpr std::string_view kStarted = R"(# the gateway
role: gateway
name: gw
backbone:
  connect: 127.0.0.1:7000   # the surface
  auth: {mode: plain}
modules:
  - id: 1
    bus: vcan1
log:
  level: info
  stats_interval_s: 10
)";

TEST(ChangedSections, OnlySectionsWhoseContentDiffers) {
  struct Row {
    std::string name;
    std::string reloaded;
    std::vector<std::string> changed;
  };
  const std::string started(kStarted);
  const auto replaced = [&](const std::string& from, const std::string& to) {
    std::string text = started;
    text.replace(text.find(from), from.size(), to);
    return text;
  };
  const std::vector<Row> table = {
      {"same text", started, {}},
      {"comments and layout only",
       replaced("  connect: 127.0.0.1:7000   # the surface\n  auth: {mode: plain}\n",
                "  auth:\n    mode: plain\n  connect: 127.0.0.1:7000\n"),
       {}},
      {"log only", replaced("level: info", "level: debug"), {"log"}},
      {"a module's bus", replaced("bus: vcan1", "bus: vcan2"), {"modules"}},
      {"two sections",
       replaced("name: gw\n", "name: gw2\n") + "can: {receive_buffer_bytes: 1}\n",
       {"name", "can"}},
      {"a section removed", replaced("name: gw\n", ""), {"name"}},
      {"not yaml any more", "role: [", {"role", "name", "backbone", "modules", "log"}},
  };
  for (const Row& row : table) {
    SCOPED_TRACE(row.name);
    EXPECT_EQ(changed_sections(started, row.reloaded), row.changed);
  }
}

config::LogOptions log(std::string level, std::chrono::seconds interval) {
  config::LogOptions o;
  o.level = std::move(level);
  o.stats_interval = interval;
  return o;
}

TEST(ReloadPlan, AppliesLogLevelAndIntervalAndNamesTheRest) {
  const RunningLogSettings running{"info", 10s, false};
  const ReloadPlan plan = plan_reload(running, log("debug", 2s), {"backbone", "log", "modules"});
  EXPECT_EQ(plan.level, "debug");
  EXPECT_EQ(plan.stats_interval, 2s);
  EXPECT_FALSE(plan.ignored_level);
  EXPECT_EQ(plan.restart_sections, (std::vector<std::string>{"backbone", "modules"}));
  EXPECT_EQ(applied_line(plan, running, "/etc/canbridge/gateway.yaml"),
            "config reloaded from /etc/canbridge/gateway.yaml: log.level debug (was info), "
            "log.stats_interval_s 2 (was 10)");
  EXPECT_EQ(restart_line(plan), "config reload: backbone, modules changed: restart to apply");
}

TEST(ReloadPlan, UnchangedFileAppliesNothing) {
  const RunningLogSettings running{"warn", 0s, false};
  const ReloadPlan plan = plan_reload(running, log("warn", 0s), {});
  EXPECT_FALSE(plan.level);
  EXPECT_FALSE(plan.stats_interval);
  EXPECT_TRUE(plan.restart_sections.empty());
  EXPECT_EQ(applied_line(plan, running, "s.yaml"),
            "config reloaded from s.yaml: nothing to apply (log.level warn, "
            "log.stats_interval_s 0)");
  EXPECT_EQ(restart_line(plan),
            "config reload: no other setting changed (nothing needs a restart)");
}

TEST(ReloadPlan, ACommandLineLevelWinsOverTheFile) {
  const RunningLogSettings running{"trace", 10s, true};
  const ReloadPlan plan = plan_reload(running, log("error", 5s), {"log"});
  EXPECT_FALSE(plan.level);
  EXPECT_EQ(plan.ignored_level, "error");
  EXPECT_EQ(plan.stats_interval, 5s);
  EXPECT_TRUE(plan.restart_sections.empty());
  EXPECT_EQ(applied_line(plan, running, "s.yaml"),
            "config reloaded from s.yaml: log.stats_interval_s 5 (was 10); log.level error not "
            "applied: the command line set trace");
  // The same level as the command line's is no conflict.
  EXPECT_FALSE(plan_reload(running, log("trace", 10s), {}).ignored_level);
}

}  // namespace
}  // namespace canbridge::bridge
