#include "tools/link_emulator/command_line.hpp"

#include <gtest/gtest.h>

namespace canbridge::emulator {
namespace {

using namespace std::chrono_literals;

CommandLine parse(std::vector<std::string> args) {
  return parse_command_line(args);
}

TEST(CommandLine, ParsesEveryOption) {
  const CommandLine parsed = parse({"--a",
                                    "tcp-listen:127.0.0.1:0",
                                    "--b",
                                    "tcp-connect:localhost:7000",
                                    "--baud",
                                    "115200",
                                    "--bits-per-byte",
                                    "11",
                                    "--latency-ms",
                                    "2.5",
                                    "--jitter-ms",
                                    "1",
                                    "--ber",
                                    "1e-4",
                                    "--loss",
                                    "0.001",
                                    "--buffer-bytes",
                                    "4096",
                                    "--seed",
                                    "99",
                                    "--cuts",
                                    "10",
                                    "--cut-ms",
                                    "500:1500",
                                    "--cut-window-s",
                                    "5:65",
                                    "--cut-gap-ms",
                                    "200",
                                    "--stats-seconds",
                                    "5"});
  ASSERT_TRUE(parsed.options) << parsed.error;
  const EmulatorOptions& options = *parsed.options;
  EXPECT_EQ(options.a.kind, EndpointSpec::Kind::tcp_listen);
  EXPECT_EQ(options.a.host, "127.0.0.1");
  EXPECT_EQ(options.a.port, 0);
  EXPECT_EQ(options.b.kind, EndpointSpec::Kind::tcp_connect);
  EXPECT_EQ(options.b.host, "localhost");
  EXPECT_EQ(options.b.port, 7000);
  EXPECT_EQ(options.line.bandwidth_bps, 115200u);
  EXPECT_EQ(options.line.bits_per_byte, 11u);
  EXPECT_EQ(options.line.latency, 2500us);
  EXPECT_EQ(options.line.jitter, 1ms);
  EXPECT_DOUBLE_EQ(options.line.bit_error_rate, 1e-4);
  EXPECT_DOUBLE_EQ(options.line.byte_loss_rate, 0.001);
  EXPECT_EQ(options.line.buffer_limit, 4096u);
  EXPECT_EQ(options.seed, 99u);
  EXPECT_EQ(options.stats_interval, 5s);
  ASSERT_EQ(options.cuts.cuts().size(), 10u);
  for (const Cut& cut : options.cuts.cuts()) {
    EXPECT_GE(cut.length, 500ms);
    EXPECT_LE(cut.length, 1500ms);
    EXPECT_GE(cut.start, 5s);
    EXPECT_LE(cut.end(), 65s);
  }
  EXPECT_NE(options.a_to_b().seed, options.b_to_a().seed);
}

TEST(CommandLine, DefaultsAreAPerfectLine) {
  const CommandLine parsed = parse({"--a", "pty:/tmp/x/gw", "--b", "pty:/tmp/x/surface"});
  ASSERT_TRUE(parsed.options) << parsed.error;
  EXPECT_EQ(parsed.options->a.path, "/tmp/x/gw");
  EXPECT_EQ(parsed.options->line.bandwidth_bps, 0u);
  EXPECT_EQ(parsed.options->line.bits_per_byte, 10u);
  EXPECT_EQ(parsed.options->line.bit_error_rate, 0.0);
  EXPECT_EQ(parsed.options->line.buffer_limit, std::size_t{1} << 20);
  EXPECT_TRUE(parsed.options->cuts.empty());
}

TEST(CommandLine, CutModeIsCloseUnlessSilentIsAsked) {
  const auto close = parse({"--a", "pty:/tmp/a", "--b", "pty:/tmp/b"});
  ASSERT_TRUE(close.options) << close.error;
  EXPECT_EQ(close.options->cut_mode, emulator::EmulatorOptions::CutMode::close);
  const auto silent = parse({"--a", "pty:/tmp/a", "--b", "pty:/tmp/b", "--cut-mode=silent"});
  ASSERT_TRUE(silent.options) << silent.error;
  EXPECT_EQ(silent.options->cut_mode, emulator::EmulatorOptions::CutMode::silent);
}

TEST(CommandLine, ExplicitCutsInSeconds) {
  const CommandLine parsed =
      parse({"--a", "pty:/tmp/a", "--b", "pty:/tmp/b", "--cut-at", "10+2.5", "--cut-at", "3+0.5"});
  ASSERT_TRUE(parsed.options) << parsed.error;
  ASSERT_EQ(parsed.options->cuts.cuts().size(), 2u);
  EXPECT_EQ(parsed.options->cuts.cuts()[0].start, 3s);
  EXPECT_EQ(parsed.options->cuts.cuts()[0].length, 500ms);
  EXPECT_EQ(parsed.options->cuts.cuts()[1].start, 10s);
  EXPECT_EQ(parsed.options->cuts.cuts()[1].length, 2500ms);
}

TEST(CommandLine, HelpIsNotAnError) {
  const CommandLine parsed = parse({"--help"});
  EXPECT_TRUE(parsed.help);
  EXPECT_FALSE(parsed.options);
}

TEST(CommandLine, OptionsInAnyOrderAndEitherSpelling) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--a", "pty:/tmp/a", "--b", "tcp-listen:127.0.0.1:0", "--baud", "9600", "--ber",
            "1e-5"},
           {"--ber=1e-5", "--b=tcp-listen:127.0.0.1:0", "--baud=9600", "--a=pty:/tmp/a"},
           {"--baud", "9600", "--b", "tcp-listen:127.0.0.1:0", "--ber", "1e-5", "--a",
            "pty:/tmp/a"},
       }) {
    const CommandLine parsed = parse(args);
    ASSERT_TRUE(parsed.options) << parsed.error;
    EXPECT_EQ(parsed.options->a.path, "/tmp/a");
    EXPECT_EQ(parsed.options->b.kind, EndpointSpec::Kind::tcp_listen);
    EXPECT_EQ(parsed.options->line.bandwidth_bps, 9600u);
    EXPECT_DOUBLE_EQ(parsed.options->line.bit_error_rate, 1e-5);
  }
}

TEST(CommandLine, VersionAndLogOptions) {
  EXPECT_TRUE(parse({"--version"}).version);
  EXPECT_TRUE(parse({"--a", "pty:/tmp/a", "--version"}).version);
  const CommandLine plain = parse({"--a", "pty:/tmp/a", "--b", "pty:/tmp/b"});
  EXPECT_FALSE(plain.log_level);
  EXPECT_EQ(plain.log_format, logging::LogFormat::automatic);
  const CommandLine verbose = parse({"-vv", "--a", "pty:/tmp/a", "--b", "pty:/tmp/b"});
  EXPECT_EQ(verbose.log_level, "trace");
  const CommandLine journal = parse(
      {"--a", "pty:/tmp/a", "--b", "pty:/tmp/b", "--log-level=warn", "--log-format", "journal"});
  ASSERT_TRUE(journal.options) << journal.error;
  EXPECT_EQ(journal.log_level, "warn");
  EXPECT_EQ(journal.log_format, logging::LogFormat::journal);
}

TEST(CommandLine, BadArgumentsSayWhatIsWrong) {
  const std::vector<std::string> ends{"--a", "pty:/tmp/a", "--b", "pty:/tmp/b"};
  const auto with = [&](std::vector<std::string> extra) {
    extra.insert(extra.begin(), ends.begin(), ends.end());
    return parse(extra);
  };
  const auto expect_error = [](const CommandLine& parsed, const std::string& needle) {
    EXPECT_FALSE(parsed.options);
    EXPECT_NE(parsed.error.find(needle), std::string::npos) << parsed.error;
  };
  expect_error(parse({"--a", "pty:/tmp/a"}), "--b");
  expect_error(parse({"--a", "serial:/dev/ttyS0", "--b", "pty:/tmp/b"}), "serial:/dev/ttyS0");
  expect_error(parse({"--a", "tcp-connect:127.0.0.1:0", "--b", "pty:/tmp/b"}), "port");
  expect_error(parse({"--a", "tcp-listen:127.0.0.1", "--b", "pty:/tmp/b"}), "HOST:PORT");
  expect_error(parse({"--a", "pty:/tmp/a", "--b", "pty:/tmp/a"}), "same pty");
  expect_error(with({"--baud"}), "needs a value");
  expect_error(with({"--baud", "fast"}), "--baud");
  expect_error(with({"--ber", "2"}), "--ber");
  expect_error(with({"--loss", "-0.1"}), "--loss");
  expect_error(with({"--latency-ms", "x"}), "--latency-ms");
  expect_error(with({"--frobnicate", "1"}), "unexpected argument(s): --frobnicate 1");
  expect_error(with({"--log-level", "loud"}), "--log-level");
  expect_error(with({"-v", "--log-level", "info"}), "excludes");
  expect_error(with({"--cuts", "3"}), "--cut-ms");
  expect_error(with({"--cut-ms", "100"}), "--cuts");
  expect_error(with({"--cuts", "3", "--cut-ms", "100", "--cut-window-s", "5"}), "X:Y");
  expect_error(with({"--cuts", "20", "--cut-ms", "1000", "--cut-window-s", "0:10"}), "fit");
  expect_error(
      with({"--cuts", "1", "--cut-ms", "100", "--cut-window-s", "0:10", "--cut-at", "1+1"}),
      "exclude");
  expect_error(with({"--cut-at", "5"}), "--cut-at");
  expect_error(with({"--cut-at", "1+2", "--cut-at", "2+1"}), "overlap");
  expect_error(with({"--cut-mode", "quiet"}), "--cut-mode: close or silent");
}

TEST(CommandLine, EndpointSpecsRoundTrip) {
  std::string error;
  for (const std::string text : {"tcp-listen:127.0.0.1:0", "tcp-connect:example.org:5000",
                                 "tcp-listen:[::1]:7", "pty:/tmp/x/gw"}) {
    const auto spec = parse_endpoint(text, error);
    ASSERT_TRUE(spec) << error;
    EXPECT_EQ(to_string(*spec), text);
  }
  EXPECT_EQ(parse_endpoint("tcp-listen:[::1]:7", error)->host, "::1");
}

TEST(CommandLine, ReadyLineRoundTrip) {
  const std::string output =
      "something else\n" +
      format_ready_line("tcp-listen:127.0.0.1:41234", "pty:/tmp/x/surface->/dev/pts/5") +
      "\nlink-emulator: cut 1/3 begins\n";
  const auto ready = find_ready_line(output);
  ASSERT_TRUE(ready);
  EXPECT_EQ(ready->a, "tcp-listen:127.0.0.1:41234");
  EXPECT_EQ(ready->b, "pty:/tmp/x/surface->/dev/pts/5");
  EXPECT_EQ(endpoint_port(ready->a), 41234);
  EXPECT_EQ(endpoint_port(ready->b), std::nullopt);
  EXPECT_EQ(endpoint_pty_device(ready->b), "/dev/pts/5");
  EXPECT_EQ(endpoint_pty_device(ready->a), std::nullopt);
  EXPECT_FALSE(
      find_ready_line("link-emulator: ready a=tcp-listen:127.0.0.1:1 b=pty:/x->/dev/pts/"));
}

TEST(CommandLine, StatsLineNamesEveryCounter) {
  ImpairmentCounters a_to_b;
  a_to_b.bytes_in = 10;
  a_to_b.bytes_out = 9;
  a_to_b.bits_flipped = 3;
  a_to_b.bytes_lost = 1;
  a_to_b.bytes_dropped_in_cut = 4;
  a_to_b.bytes_dropped_on_disconnect = 5;
  EXPECT_EQ(format_stats("final stats", a_to_b, {}),
            "link-emulator: final stats a->b in=10 out=9 flipped=3 lost=1 cut_dropped=4 "
            "disconnect_dropped=5 b->a in=0 out=0 flipped=0 lost=0 cut_dropped=0 "
            "disconnect_dropped=0");
}

}  // namespace
}  // namespace canbridge::emulator
