// The operator commands' grammar: every command's --help lists every option it takes, a bad
// command line is named in one line with exit status 2 before anything connects, and options
// may stand anywhere.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include "app/cli_reply.hpp"
#include "tests/cli/cli_test_support.hpp"
#include "tests/cli/fake_endpoint.hpp"

namespace canbridge::test {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;
namespace exit_code = cli::exit_code;

constexpr const char* kNoEndpoint = "/nonexistent/canbridge.sock";

std::size_t line_count(const std::string& text) {
  return static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n'));
}

TEST(CliGrammar, EveryCommandsHelpListsEveryOptionWithItsDefault) {
  const std::vector<std::vector<std::string>> commands = {
      {"nodes"}, {"stats"},       {"sdo", "read"}, {"sdo", "write"}, {"nmt"},
      {"flash"}, {"set-node-id"}, {"dump"},        {"capture"}};
  for (auto args : commands) {
    args.push_back("--help");
    const auto run = run_cli(args);
    EXPECT_EQ(run.rc, exit_code::ok) << args[0];
    for (const char* option : {"--endpoint", "--token-file", "--config", "--net", "--timeout"}) {
      EXPECT_THAT(run.out, HasSubstr(option)) << args[0] << " --help lacks " << option;
    }
    EXPECT_THAT(run.out, HasSubstr("=30")) << args[0] << ": --timeout's default";
  }
  const auto read = run_cli({"sdo", "read", "--help"});
  for (const char* positional : {"NODE", "INDEX", "SUB", "TYPE"}) {
    EXPECT_THAT(read.out, HasSubstr(positional));
  }
  EXPECT_THAT(read.out, HasSubstr("1..127")) << "the positionals are described";
}

// cmd's lines name their networks: it takes every common option but --net, and says what a line
// is and where the lines come from without one.
TEST(CliGrammar, CmdsHelpListsItsOptionsAndLines) {
  const auto run = run_cli({"cmd", "--help"});
  EXPECT_EQ(run.rc, exit_code::ok);
  for (const char* option : {"--endpoint", "--token-file", "--config", "--timeout", "LINE"}) {
    EXPECT_THAT(run.out, HasSubstr(option)) << "cmd --help lacks " << option;
  }
  EXPECT_THAT(run.out, Not(HasSubstr("--net")));
  EXPECT_THAT(run.out, HasSubstr("standard input"));
  const auto top = run_cli({"--help"});
  EXPECT_THAT(top.out, HasSubstr("cmd"));
}

TEST(CliGrammar, AnUnknownSdoCommandIsNamedInOneLine) {
  const auto run = run_cli({"sdo", "frob", "5", "0x1000", "0", "--endpoint", kNoEndpoint});
  EXPECT_EQ(run.rc, exit_code::usage);
  EXPECT_THAT(run.err, HasSubstr("unknown sdo command 'frob': expected read or write"));
  EXPECT_LE(line_count(run.err), 2u) << run.err;
}

TEST(CliGrammar, BadNumbersAreNamedWithTheirRange) {
  const auto timeout = run_cli({"nodes", "--timeout", "abc", "--endpoint", kNoEndpoint});
  EXPECT_EQ(timeout.rc, exit_code::usage);
  EXPECT_THAT(timeout.err, HasSubstr("'abc' is not a number of seconds"));
  EXPECT_LT(timeout.err.size(), 200u) << "no 300-digit range: " << timeout.err;
  const auto zero = run_cli({"nodes", "--timeout", "0", "--endpoint", kNoEndpoint});
  EXPECT_EQ(zero.rc, exit_code::usage);
  const auto net = run_cli({"nodes", "--net", "99999999", "--endpoint", kNoEndpoint});
  EXPECT_EQ(net.rc, exit_code::usage);
  EXPECT_THAT(net.err, HasSubstr("'99999999' is not a network 0..65535"));
}

TEST(CliGrammar, AMissingArgumentIsOneLineNotTheWholeHelp) {
  const auto run = run_cli({"sdo", "read", "5", "--endpoint", kNoEndpoint});
  EXPECT_EQ(run.rc, exit_code::usage);
  EXPECT_THAT(run.err, HasSubstr("INDEX"));
  EXPECT_THAT(run.err, HasSubstr("run 'canbridge sdo read --help'"));
  EXPECT_THAT(run.err, Not(HasSubstr("Options:")));
  EXPECT_LE(line_count(run.err), 2u) << run.err;
}

TEST(CliGrammar, OptionsStandBeforeBetweenOrAfterTheCommandWords) {
  FakeEndpoint endpoint(Script{{"[1] 2 5 r 0x1000 0 u32", {"[1] 4660"}}});
  const auto run = run_cli(
      {"--endpoint", endpoint.address(), "sdo", "--net", "2", "read", "5", "1000", "0", "u32"});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "4660\n");
}

class CliStatsConfig : public ::testing::Test {
 protected:
  std::filesystem::path file(const std::string& name, const std::string& text) {
    const auto path = dir_ / name;
    std::ofstream(path) << text;
    return path;
  }
  void SetUp() override { std::filesystem::create_directories(dir_); }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::filesystem::path dir_ = std::filesystem::temp_directory_path() /
                               ("canbridge-cli-grammar-" + std::to_string(::getpid()));
};

TEST_F(CliStatsConfig, StatsReadsAGatewaysStatsEndpoint) {
  FakeEndpoint endpoint(Script{{"[1] stats", {"[1] {\"role\":\"gateway\"}", "[1] OK"}}});
  const auto config =
      file("gateway.yaml",
           "role: gateway\nname: g\nstats_endpoint: " + endpoint.address() + "\nmodules: []\n");
  const auto run = run_cli({"stats", "-c", config.string()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "{\"role\":\"gateway\"}\n");
}

TEST_F(CliStatsConfig, AGatewaysFileWithoutStatsEndpointIsNamed) {
  const auto config = file("gateway.yaml", "role: gateway\nname: g\nmodules: []\n");
  const auto stats = run_cli({"stats", "-c", config.string()});
  EXPECT_EQ(stats.rc, exit_code::usage);
  EXPECT_THAT(stats.err, HasSubstr("it sets no stats_endpoint"));
  const auto nodes = run_cli({"nodes", "-c", config.string()});
  EXPECT_EQ(nodes.rc, exit_code::usage);
  EXPECT_THAT(nodes.err, HasSubstr("is a gateway's configuration"));
}

TEST_F(CliStatsConfig, TheShippedSamplesAreReadForTheirEndpoint) {
  // config/gateway.yaml leaves stats_endpoint commented out: named, not a YAML error.
  const auto gateway = run_cli({"stats", "-c", CANBRIDGE_SOURCE_DIR "/config/gateway.yaml"});
  EXPECT_EQ(gateway.rc, exit_code::usage);
  EXPECT_THAT(gateway.err, HasSubstr("it sets no stats_endpoint"));
  EXPECT_THAT(gateway.err, Not(HasSubstr("invalid node")));
}

}  // namespace
}  // namespace canbridge::test
