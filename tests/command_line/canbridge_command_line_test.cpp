#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "app/command_line.hpp"

namespace canbridge::bridge {
namespace {

constexpr std::string_view kConfigDir = "/etc/canbridge";

CommandLine parse(const std::vector<std::string>& args) {
  return parse_command_line(args, kConfigDir, "9.8.7");
}

std::string joined(const std::vector<std::string>& args) {
  std::string s;
  for (const auto& a : args) s += " " + a;
  return s;
}

struct Good {
  std::vector<std::string> args;
  Command command;
  std::string config_path;
  bool config_given;
  std::optional<std::uint32_t> lss_module;
  std::optional<std::string> log_level;
  logging::LogFormat log_format = logging::LogFormat::automatic;
};

TEST(CanbridgeCommandLine, GoodCommandLinesInAnyOrderAndSpelling) {
  using logging::LogFormat;
  const std::vector<Good> table = {
      {{"gateway", "--config", "g.yaml"}, Command::gateway, "g.yaml", true, {}, {}},
      {{"gateway", "--config=g.yaml"}, Command::gateway, "g.yaml", true, {}, {}},
      {{"gateway", "-c", "g.yaml"}, Command::gateway, "g.yaml", true, {}, {}},
      {{"gateway", "--config", "g.yaml", "--lss-module", "2"},
       Command::gateway,
       "g.yaml",
       true,
       2,
       {}},
      // The order the old parser refused.
      {{"gateway", "--lss-module", "1", "--config", "g.yaml"},
       Command::gateway,
       "g.yaml",
       true,
       1,
       {}},
      {{"gateway", "--lss-module=3", "-c", "g.yaml", "-v"},
       Command::gateway,
       "g.yaml",
       true,
       3,
       "debug"},
      {{"gateway"}, Command::gateway, "/etc/canbridge/gateway.yaml", false, {}, {}},
      {{"surface"}, Command::surface, "/etc/canbridge/surface.yaml", false, {}, {}},
      {{"surface", "-vv", "-c", "s.yaml"}, Command::surface, "s.yaml", true, {}, "trace"},
      {{"surface", "-v", "-v"},
       Command::surface,
       "/etc/canbridge/surface.yaml",
       false,
       {},
       "trace"},
      {{"surface", "--log-level", "warn", "--config", "s.yaml"},
       Command::surface,
       "s.yaml",
       true,
       {},
       "warn"},
      {{"surface", "--log-format", "journal", "--log-level=error"},
       Command::surface,
       "/etc/canbridge/surface.yaml",
       false,
       {},
       "error",
       LogFormat::journal},
      {{"gateway", "--log-format=text", "-c", "g.yaml"},
       Command::gateway,
       "g.yaml",
       true,
       {},
       {},
       LogFormat::text},
  };
  for (const Good& row : table) {
    SCOPED_TRACE(joined(row.args));
    const CommandLine parsed = parse(row.args);
    ASSERT_EQ(parsed.command, row.command) << parsed.error;
    EXPECT_EQ(parsed.config_path, row.config_path);
    EXPECT_EQ(parsed.config_given, row.config_given);
    EXPECT_EQ(parsed.lss_module, row.lss_module);
    EXPECT_EQ(parsed.log_level, row.log_level);
    EXPECT_EQ(parsed.log_format, row.log_format);
  }
}

TEST(CanbridgeCommandLine, DemoTakesItsSizes) {
  const CommandLine defaults = parse({"demo"});
  ASSERT_EQ(defaults.command, Command::demo) << defaults.error;
  EXPECT_EQ(defaults.demo.modules, 2u);
  EXPECT_EQ(defaults.demo.nodes_per_module, 4u);
  const CommandLine sized = parse({"demo", "--nodes", "31", "--modules=4"});
  ASSERT_EQ(sized.command, Command::demo) << sized.error;
  EXPECT_EQ(sized.demo.modules, 4u);
  EXPECT_EQ(sized.demo.nodes_per_module, 31u);
}

TEST(CanbridgeCommandLine, OperatorCommandsGoToTheirOwnParser) {
  const std::vector<std::string> args = {"sdo", "read", "5", "1018", "1", "--net", "2"};
  const CommandLine parsed = parse(args);
  ASSERT_EQ(parsed.command, Command::client);
  EXPECT_EQ(parsed.client_args, args);
}

TEST(CanbridgeCommandLine, HelpForEveryCommandAndVersionEverywhere) {
  struct Row {
    std::vector<std::string> args;
    std::string needle;  // in the output
  };
  const std::vector<Row> table = {
      {{"--help"}, "gateway"},
      {{"-h"}, "Subcommands"},
      {{"--help"}, "nodes, sdo, nmt"},
      {{"gateway", "--help"}, "--lss-module"},
      {{"gateway", "-c", "g.yaml", "--help"}, "/etc/canbridge/gateway.yaml"},
      {{"surface", "--help"}, "--log-format"},
      {{"surface", "-h"}, "/etc/canbridge/surface.yaml"},
      {{"demo", "--help"}, "--modules"},
      {{"--version"}, "canbridge 9.8.7\n"},
      {{"gateway", "--version"}, "canbridge 9.8.7\n"},
      {{"surface", "-c", "s.yaml", "--version"}, "canbridge 9.8.7\n"},
      {{"demo", "--version"}, "canbridge 9.8.7\n"},
      {{"nodes", "--version"}, "canbridge 9.8.7\n"},
  };
  for (const Row& row : table) {
    SCOPED_TRACE(joined(row.args));
    const CommandLine parsed = parse(row.args);
    ASSERT_EQ(parsed.command, Command::done);
    EXPECT_EQ(parsed.exit_status, 0);
    EXPECT_EQ(parsed.error, "");
    EXPECT_NE(parsed.output.find(row.needle), std::string::npos) << parsed.output;
  }
  // Each command's help is its own: the surface's does not offer the gateway's options.
  EXPECT_EQ(parse({"surface", "--help"}).output.find("--lss-module"), std::string::npos);
}

TEST(CanbridgeCommandLine, BadCommandLinesExit2SayingWhatWasExpected) {
  struct Row {
    std::vector<std::string> args;
    std::vector<std::string> needles;  // in the error
  };
  const std::vector<Row> table = {
      {{}, {"no command given", "expected gateway, surface, demo"}},
      {{"frobnicate"}, {"unknown command 'frobnicate'", "expected gateway, surface, demo"}},
      {{"gateway", "--config"}, {"--config", "canbridge gateway --help"}},
      {{"gateway", "--lss-module", "x", "-c", "g.yaml"}, {"--lss-module", "expected a number"}},
      {{"surface", "--lss-module", "1"}, {"--lss-module", "canbridge surface --help"}},
      {{"gateway", "-c", "g.yaml", "extra", "words"}, {"unexpected argument(s): extra words"}},
      {{"gateway", "--log-level", "loud"}, {"--log-level", "trace,debug,info,warn,error,off"}},
      {{"gateway", "-v", "--log-level", "info"}, {"--verbose excludes --log-level"}},
      {{"surface", "--log-format", "xml"}, {"--log-format", "auto,text,journal"}},
      {{"demo", "--modules", "7"}, {"--modules", "1 to 4"}},
      {{"demo", "--nodes", "0"}, {"--nodes", "1 to 31"}},
      {{"demo", "--modules"}, {"--modules", "canbridge demo --help"}},
      {{"gateway", "surface"}, {"canbridge gateway"}},
  };
  for (const Row& row : table) {
    SCOPED_TRACE(joined(row.args));
    const CommandLine parsed = parse(row.args);
    ASSERT_EQ(parsed.command, Command::done);
    EXPECT_EQ(parsed.exit_status, 2);
    EXPECT_EQ(parsed.output, "");
    for (const std::string& needle : row.needles) {
      EXPECT_NE(parsed.error.find(needle), std::string::npos) << parsed.error;
    }
  }
}

TEST(CanbridgeCommandLine, AMissingDefaultFileNamesThePathAndConfig) {
  char pattern[] = "/tmp/canbridge-config-XXXXXX";
  ASSERT_NE(::mkdtemp(pattern), nullptr);
  const std::string dir = pattern;
  const CommandLine gateway = parse_command_line({"gateway"}, dir, "1");
  const auto missing = missing_default_config(gateway);
  ASSERT_TRUE(missing);
  EXPECT_NE(missing->find(dir + "/gateway.yaml"), std::string::npos) << *missing;
  EXPECT_NE(missing->find("--config"), std::string::npos) << *missing;
  std::ofstream(dir + "/gateway.yaml") << "role: gateway\n";
  EXPECT_FALSE(missing_default_config(gateway));
  // A file named on the command line is the loader's to report (with its own message).
  EXPECT_FALSE(missing_default_config(parse_command_line({"surface", "-c", dir + "/x"}, dir, "1")));
  std::filesystem::remove(dir + "/gateway.yaml");
  std::filesystem::remove(dir);
}

}  // namespace
}  // namespace canbridge::bridge
