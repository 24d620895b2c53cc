#include <gtest/gtest.h>

#include "app/command_line.hpp"
#include "logging/command_line_common.hpp"
#include "sim/command_line.hpp"
#include "tools/link_emulator/command_line.hpp"

// The three executables share their log options and the wording of parse errors
// (logging/command_line_common): the same mistake reads the same in each.
namespace canbridge {
namespace {

struct Messages {
  std::string canbridge;
  std::string sim;
  std::string emulator;
};

// The same options after each program's own required arguments.
Messages errors_of(const std::vector<std::string>& options) {
  std::vector<std::string> canbridge = {"gateway"};
  std::vector<std::string> sim = {"rig.yaml"};
  std::vector<std::string> emulator = {"--a", "pty:/tmp/a", "--b", "pty:/tmp/b"};
  for (auto* args : {&canbridge, &sim, &emulator}) {
    args->insert(args->end(), options.begin(), options.end());
  }
  return {bridge::parse_command_line(canbridge, "/etc/canbridge", "1").error,
          sim::parse_sim_command_line(sim, "1").error,
          emulator::parse_command_line(emulator).error};
}

TEST(SharedGrammar, TheSameMistakeReadsTheSameInEveryProgram) {
  struct Row {
    std::vector<std::string> options;
    std::string message;  // after "PROGRAM: " (the emulator's has no prefix)
  };
  const std::vector<Row> table = {
      {{"--log-level", "info", "--log-level=warn"}, "--log-level: given 2 times, expected once"},
      {{"--log-format", "text", "--log-format", "journal"},
       "--log-format: given 2 times, expected once"},
      {{"--log-format"}, "--log-format needs a value (FORMAT:{auto,text,journal})"},
      {{"--frobnicate", "x", "y"}, "unexpected argument(s): --frobnicate x y"},
      {{"-v", "--log-level", "info"}, "--verbose excludes --log-level"},
      {{"--log-level", "loud"}, "--log-level: loud not in {trace,debug,info,warn,error,off}"},
  };
  for (const Row& row : table) {
    std::string trace;
    for (const auto& o : row.options) trace += " " + o;
    SCOPED_TRACE(trace);
    const Messages m = errors_of(row.options);
    EXPECT_EQ(m.canbridge,
              "canbridge: " + row.message + "\nrun 'canbridge gateway --help' for the usage\n");
    EXPECT_EQ(m.sim,
              "canbridge-sim: " + row.message + "\nrun 'canbridge-sim --help' for the usage\n");
    EXPECT_EQ(m.emulator, row.message);
  }
}

TEST(SharedGrammar, LogArgumentsResolveLevelAndFormat) {
  logging::LogArguments log;
  EXPECT_FALSE(log.log_level());
  EXPECT_EQ(log.log_format(), logging::LogFormat::automatic);
  log.verbosity = 1;
  EXPECT_EQ(log.log_level(), "debug");
  log.verbosity = 3;
  EXPECT_EQ(log.log_level(), "trace");
  log.level = "warn";  // --log-level wins (the parsers refuse both together anyway)
  EXPECT_EQ(log.log_level(), "warn");
  log.format = "journal";
  EXPECT_EQ(log.log_format(), logging::LogFormat::journal);
}

}  // namespace
}  // namespace canbridge
