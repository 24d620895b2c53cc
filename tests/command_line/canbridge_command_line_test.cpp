#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "app/cli_main.hpp"
#include "app/cli_reply.hpp"
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

// The role's options may stand before its name, with the same meaning as after it.
TEST(CanbridgeCommandLine, OptionsBeforeTheCommandNameMeanTheSame) {
  using logging::LogFormat;
  struct Row {
    std::vector<std::string> before;
    std::vector<std::string> after;  // the same options after the name
    Good expected;
  };
  const std::vector<Row> table = {
      {{"-v", "gateway", "-c", "F"},
       {"gateway", "-c", "F", "-v"},
       {{}, Command::gateway, "F", true, {}, "debug"}},
      {{"--log-level", "debug", "surface", "--config=F"},
       {"surface", "--config=F", "--log-level", "debug"},
       {{}, Command::surface, "F", true, {}, "debug"}},
      {{"-c", "F", "gateway"}, {"gateway", "-c", "F"}, {{}, Command::gateway, "F", true, {}, {}}},
      {{"--log-format", "journal", "gateway", "-c", "F"},
       {"gateway", "-c", "F", "--log-format", "journal"},
       {{}, Command::gateway, "F", true, {}, {}, LogFormat::journal}},
      {{"--lss-module", "2", "-vv", "gateway"},
       {"gateway", "--lss-module", "2", "-vv"},
       {{}, Command::gateway, "/etc/canbridge/gateway.yaml", false, 2, "trace"}},
      {{"--config", "s.yaml", "--log-format=text", "surface", "--log-level=warn"},
       {"surface", "--config", "s.yaml", "--log-format=text", "--log-level=warn"},
       {{}, Command::surface, "s.yaml", true, {}, "warn", LogFormat::text}},
      // The value of -c is not taken for the command, even when it is spelled like one.
      {{"-c", "surface", "gateway"},
       {"gateway", "-c", "surface"},
       {{}, Command::gateway, "surface", true, {}, {}}},
      // -v counts wherever it stands.
      {{"-v", "surface", "-v"},
       {"surface", "-vv"},
       {{}, Command::surface, "/etc/canbridge/surface.yaml", false, {}, "trace"}},
  };
  for (const Row& row : table) {
    for (const auto& args : {row.before, row.after}) {
      SCOPED_TRACE(joined(args));
      const CommandLine parsed = parse(args);
      ASSERT_EQ(parsed.command, row.expected.command) << parsed.error;
      EXPECT_EQ(parsed.config_path, row.expected.config_path);
      EXPECT_EQ(parsed.config_given, row.expected.config_given);
      EXPECT_EQ(parsed.lss_module, row.expected.lss_module);
      EXPECT_EQ(parsed.log_level, row.expected.log_level);
      EXPECT_EQ(parsed.log_format, row.expected.log_format);
    }
  }
  const CommandLine demo = parse({"--modules", "3", "demo", "--nodes=5"});
  ASSERT_EQ(demo.command, Command::demo) << demo.error;
  EXPECT_EQ(demo.demo.modules, 3u);
  EXPECT_EQ(demo.demo.nodes_per_module, 5u);
}

// An option that takes one value is refused when given twice, before or after the name alike,
// and an option of another command is refused naming the command it belongs to.
TEST(CanbridgeCommandLine, OptionsBeforeTheNameAreRefusedLikeAfterIt) {
  struct Row {
    std::vector<std::string> args;
    std::string error;  // exactly
  };
  const std::string usage_gateway = "\nrun 'canbridge gateway --help' for the usage\n";
  const std::string usage_surface = "\nrun 'canbridge surface --help' for the usage\n";
  const std::string usage_demo = "\nrun 'canbridge demo --help' for the usage\n";
  const std::string usage = "\nrun 'canbridge --help' for the usage\n";
  const std::string roles =
      "expected gateway, surface, demo, check or an operator command (nodes, sdo, nmt, "
      "set-node-id, flash, dump, capture, stats)";
  const std::vector<Row> table = {
      {{"-c", "a.yaml", "gateway", "-c", "b.yaml"},
       "canbridge: --config: given 2 times, expected once" + usage_gateway},
      {{"gateway", "-c", "a.yaml", "--config=b.yaml"},
       "canbridge: --config: given 2 times, expected once" + usage_gateway},
      {{"--log-level", "info", "surface", "--log-level", "warn"},
       "canbridge: --log-level: given 2 times, expected once" + usage_surface},
      {{"-v", "gateway", "--log-level", "info"},
       "canbridge: --verbose excludes --log-level" + usage_gateway},
      {{"--lss-module", "1", "surface"},
       "canbridge: unexpected argument(s): --lss-module 1 (--lss-module is an option of gateway "
       "only)" +
           usage_surface},
      {{"--lss-module=1", "demo"},
       "canbridge: unexpected argument(s): --lss-module=1 (--lss-module is an option of gateway "
       "only)" +
           usage_demo},
      {{"-c", "F", "demo"},
       "canbridge: unexpected argument(s): -c F (-c is an option of gateway, surface, check "
       "only)" +
           usage_demo},
      {{"--log-level", "debug", "demo"},
       "canbridge: unexpected argument(s): --log-level debug (--log-level is an option of "
       "gateway, surface only)" +
           usage_demo},
      {{"--frobnicate", "gateway"},
       "canbridge: unexpected argument(s): --frobnicate" + usage_gateway},
      {{"-v", "frobnicate"}, "canbridge: unknown command 'frobnicate': " + roles + usage},
      {{"-c", "F"}, "canbridge: no command given: " + roles + usage},
  };
  for (const Row& row : table) {
    SCOPED_TRACE(joined(row.args));
    const CommandLine parsed = parse(row.args);
    ASSERT_EQ(parsed.command, Command::done);
    EXPECT_EQ(parsed.exit_status, 2);
    EXPECT_EQ(parsed.output, "");
    EXPECT_EQ(parsed.error, row.error);
  }
}

TEST(CanbridgeCommandLine, HelpAndVersionAfterOptionsBeforeTheName) {
  const std::string gateway_help = parse({"gateway", "--help"}).output;
  EXPECT_NE(gateway_help.find("--lss-module"), std::string::npos) << gateway_help;
  EXPECT_EQ(parse({"-v", "gateway", "--help"}).output, gateway_help);
  EXPECT_EQ(parse({"-c", "F", "gateway", "-h"}).output, gateway_help);
  const std::string demo_help = parse({"demo", "--help"}).output;
  EXPECT_NE(demo_help.find("--modules"), std::string::npos) << demo_help;
  // Help wins over an option demo does not have, as it does after the name.
  EXPECT_EQ(parse({"--log-level", "debug", "demo", "--help"}).output, demo_help);
  // Every help says where options may stand and what a repeated one does.
  for (const auto& args : std::vector<std::vector<std::string>>{
           {"--help"}, {"gateway", "--help"}, {"surface", "--help"}, {"demo", "--help"}}) {
    SCOPED_TRACE(joined(args));
    const std::string help = parse(args).output;
    EXPECT_NE(help.find("Options may stand before or after the command name"), std::string::npos)
        << help;
    EXPECT_NE(help.find("may be given once"), std::string::npos) << help;
  }
  for (const auto& args :
       std::vector<std::vector<std::string>>{{"-v", "gateway", "--version"},
                                             {"-c", "F", "surface", "--version"},
                                             {"--endpoint", "S", "nodes", "--version"}}) {
    SCOPED_TRACE(joined(args));
    const CommandLine parsed = parse(args);
    ASSERT_EQ(parsed.command, Command::done);
    EXPECT_EQ(parsed.output, "canbridge 9.8.7\n");
  }
}

// The operator commands' common options may stand before the name: the whole line goes to their
// parser, which reads them there.
TEST(CanbridgeCommandLine, OperatorCommandsTakeTheirCommonOptionsFirst) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--endpoint", "/run/x.sock", "stats"},
           {"-c", "s.yaml", "--net", "2", "nodes"},
           {"--timeout=5", "sdo", "read", "5", "1018", "1"},
       }) {
    SCOPED_TRACE(joined(args));
    const CommandLine parsed = parse(args);
    ASSERT_EQ(parsed.command, Command::client) << parsed.error;
    EXPECT_EQ(parsed.client_args, args);
  }
  // Their parser refuses before connecting: a bad value of a common option before the name...
  std::ostringstream out;
  std::ostringstream err;
  EXPECT_EQ(cli::run_client({"--timeout", "0", "stats"}, out, err, false), cli::exit_code::usage);
  EXPECT_EQ(err.str().rfind("canbridge: --timeout: '0' is not a number of seconds above 0", 0), 0u)
      << err.str();
  // ... and an unknown one, named as given.
  err.str("");
  EXPECT_EQ(cli::run_client({"--frobnicate", "stats"}, out, err, false), cli::exit_code::usage);
  EXPECT_EQ(err.str().rfind("canbridge: unexpected argument(s): --frobnicate\n", 0), 0u)
      << err.str();
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
