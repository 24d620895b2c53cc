#include <gtest/gtest.h>

#include "sim/command_line.hpp"

namespace canbridge::sim {
namespace {

SimCommandLine parse(const std::vector<std::string>& args) {
  return parse_sim_command_line(args, "9.8.7");
}

std::string joined(const std::vector<std::string>& args) {
  std::string s;
  for (const auto& a : args) s += " " + a;
  return s;
}

TEST(SimCommandLine, OptionsInAnyOrder) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"rig.yaml", "--bus", "a", "--bus", "b", "--interface", "a=vcan3", "--virtual",
            "--stats-seconds", "0", "--verbose"},
           {"--bus=a", "--virtual", "--interface=a=vcan3", "-v", "--stats-seconds=0", "rig.yaml",
            "--bus", "b"},
       }) {
    SCOPED_TRACE(joined(args));
    const SimCommandLine parsed = parse(args);
    ASSERT_TRUE(parsed.options) << parsed.error;
    const SimOptions& o = *parsed.options;
    EXPECT_EQ(o.rig_path, "rig.yaml");
    EXPECT_EQ(o.buses, (std::set<std::string>{"a", "b"}));
    EXPECT_EQ(o.interfaces, (std::map<std::string, std::string>{{"a", "vcan3"}}));
    EXPECT_TRUE(o.all_virtual);
    EXPECT_EQ(o.stats_seconds, 0u);
    EXPECT_EQ(o.log_level, "debug");
  }
}

TEST(SimCommandLine, DefaultsAndLogOptions) {
  const SimCommandLine plain = parse({"rig.yaml"});
  ASSERT_TRUE(plain.options) << plain.error;
  EXPECT_TRUE(plain.options->buses.empty());
  EXPECT_FALSE(plain.options->all_virtual);
  EXPECT_EQ(plain.options->stats_seconds, 10u);
  EXPECT_FALSE(plain.options->log_level);
  EXPECT_EQ(plain.options->log_format, logging::LogFormat::automatic);
  const SimCommandLine logged =
      parse({"--log-level", "warn", "--log-format", "journal", "rig.yaml"});
  ASSERT_TRUE(logged.options) << logged.error;
  EXPECT_EQ(logged.options->log_level, "warn");
  EXPECT_EQ(logged.options->log_format, logging::LogFormat::journal);
  EXPECT_EQ(parse({"rig.yaml", "-vv"}).options->log_level, "trace");
}

TEST(SimCommandLine, HelpAndVersion) {
  for (const std::vector<std::string>& args :
       std::vector<std::vector<std::string>>{{"--help"}, {"-h"}, {"rig.yaml", "--help"}}) {
    const SimCommandLine parsed = parse(args);
    EXPECT_FALSE(parsed.options);
    EXPECT_EQ(parsed.exit_status, 0);
    EXPECT_NE(parsed.output.find("--interface"), std::string::npos) << parsed.output;
  }
  const SimCommandLine version = parse({"--version"});
  EXPECT_FALSE(version.options);
  EXPECT_EQ(version.exit_status, 0);
  EXPECT_EQ(version.output, "canbridge-sim 9.8.7\n");
}

TEST(SimCommandLine, BadCommandLinesExit2SayingWhatWasExpected) {
  struct Row {
    std::vector<std::string> args;
    std::string needle;
  };
  const std::vector<Row> table = {
      {{}, "RIG is required"},
      {{"--virtual"}, "RIG is required"},
      {{"a.yaml", "b.yaml"}, "unexpected argument(s): b.yaml"},
      {{"rig.yaml", "--interface", "a"}, "'a' is not BUS=IFACE"},
      {{"rig.yaml", "--interface", "=vcan0"}, "is not BUS=IFACE"},
      {{"rig.yaml", "--stats-seconds", "often"}, "expected a number"},
      {{"rig.yaml", "--bus"}, "--bus"},
      {{"rig.yaml", "--stats-seconds", "1", "--stats-seconds=2"},
       "--stats-seconds: given 2 times, expected once"},
      {{"--virtual", "a.yaml", "b.yaml", "c.yaml"}, "unexpected argument(s): b.yaml c.yaml"},
      {{"rig.yaml", "--frobnicate"}, "unexpected argument(s): --frobnicate"},
      {{"rig.yaml", "--log-level", "loud"}, "--log-level"},
  };
  for (const Row& row : table) {
    SCOPED_TRACE(joined(row.args));
    const SimCommandLine parsed = parse(row.args);
    EXPECT_FALSE(parsed.options);
    EXPECT_EQ(parsed.exit_status, 2);
    EXPECT_NE(parsed.error.find(row.needle), std::string::npos) << parsed.error;
    EXPECT_NE(parsed.error.find("canbridge-sim --help"), std::string::npos) << parsed.error;
  }
}

}  // namespace
}  // namespace canbridge::sim
