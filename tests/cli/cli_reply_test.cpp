// The pure pieces of the client: response lines, exit codes, progress text, endpoint addresses.
#include "app/cli_reply.hpp"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <ext/stdio_sync_filebuf.h>
#include <sstream>
#include <string>

#include "app/cli_endpoint_client.hpp"
#include "app/cli_progress.hpp"

namespace canbridge::cli {
namespace {

TEST(CliReply, AnswerToMatchesOnlyItsSequence) {
  EXPECT_EQ(answer_to("[12] OK", 12), "OK");
  EXPECT_FALSE(answer_to("[12] OK", 1).has_value());
  EXPECT_FALSE(answer_to("[1] OK", 12).has_value());  // "[1]" is not a prefix of "[12]"' answer
  EXPECT_FALSE(answer_to("FRAME 1 0 < 000#0100", 1).has_value());
}

TEST(CliReply, ErrorsAndTheirExitCodes) {
  auto abort = parse_error("ERROR:0x06020000 #Object does not exist.");
  ASSERT_TRUE(abort);
  EXPECT_TRUE(abort->sdo_abort);
  EXPECT_EQ(abort->code, 0x06020000U);
  EXPECT_EQ(abort->text, "Object does not exist.");
  EXPECT_EQ(exit_code_for(*abort), exit_code::abort);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:0x05040000")), exit_code::timeout);
  // The spaced form of earlier canbridge versions still parses.
  EXPECT_EQ(exit_code_for(*parse_error("ERROR: 0x05040000 #SDO protocol timed out.")),
            exit_code::timeout);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:106 #Unsupported net.")), exit_code::unknown);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:107")), exit_code::unknown);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:103")), exit_code::timeout);
  // Not a time-out: the request may have been executed (the operator reads it back).
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:108 #Outcome unknown, may have been executed.")),
            exit_code::outcome_unknown);
  EXPECT_EQ(exit_code::outcome_unknown, 6);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:201")), exit_code::unreachable);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:401")), exit_code::unreachable);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:403")), exit_code::unreachable);
  EXPECT_EQ(exit_code_for(*parse_error("ERROR:101 #Syntax error.")), exit_code::abort);
  EXPECT_FALSE(parse_error("OK"));
  EXPECT_FALSE(parse_error("ERROR: zz"));
}

TEST(CliReply, ProgressNodeRowsFramesAndDrops) {
  const auto p = parse_progress("PROGRESS download 4096 262144");
  ASSERT_TRUE(p);
  EXPECT_EQ(p->step, "download");
  EXPECT_EQ(p->done, 4096u);
  EXPECT_EQ(p->total, 262144u);
  EXPECT_FALSE(parse_progress("PROGRESS download 1"));
  EXPECT_FALSE(parse_progress("PROGRESS 1 2"));
  const auto spaced = parse_progress("PROGRESS wait for loader boot-up 0 0");
  ASSERT_TRUE(spaced);
  EXPECT_EQ(spaced->step, "wait for loader boot-up");

  const auto row = parse_node_row("node net=0 module=1 profile=qd emcy=-");
  ASSERT_TRUE(row);
  EXPECT_EQ(field(*row, "module"), "1");
  EXPECT_EQ(field(*row, "profile"), "qd");
  EXPECT_EQ(field(*row, "absent"), "");

  const auto m = parse_monitor_frame("FRAME 1700000000123456 2 > 1A5#0102");
  ASSERT_TRUE(m);
  EXPECT_EQ(m->module, 2u);
  EXPECT_EQ(m->dir, '>');
  EXPECT_EQ(m->frame, can::Frame::standard(0x1A5, {1, 2}));
  EXPECT_EQ(m->frame.timestamp, std::chrono::microseconds(1700000000123456));
  const auto rtr = parse_monitor_frame("FRAME 1 0 < 705#R1");
  ASSERT_TRUE(rtr);
  EXPECT_TRUE(rtr->frame.is_remote());
  EXPECT_FALSE(parse_monitor_frame("FRAME 1 0 ? 705#00"));
  EXPECT_FALSE(parse_monitor_frame("FRAME x 0 < 705#00"));
  EXPECT_EQ(parse_dropped("DROPPED 17"), 17u);
  EXPECT_FALSE(parse_dropped("DROPPED"));
}

TEST(CliProgress, BarAndLineText) {
  const Progress half{"download", 131072, 262144};
  EXPECT_EQ(format_progress_bar(half, 0), "[##########..........]  50%  128.0/256.0 KiB  download");
  EXPECT_EQ(format_progress_bar(half, 12800),
            "[##########..........]  50%  128.0/256.0 KiB  12.5 KiB/s  0:10 left  download");
  EXPECT_EQ(format_progress_line(half, 12800),
            "download: 131072/262144 bytes (50%), 12.5 KiB/s, 0:10 left");
}

TEST(CliProgress, RateIsMeasuredOverTheStep) {
  std::ostringstream out;
  ProgressPrinter printer(out, false);
  const auto t0 = std::chrono::steady_clock::time_point{};
  printer.update({"download", 0, 100000}, t0);
  printer.update({"download", 51200, 100000}, t0 + std::chrono::seconds(2));
  EXPECT_EQ(out.str(),
            "download: 0/100000 bytes (0%)\n"
            "download: 51200/100000 bytes (51%), 25.0 KiB/s, 0:02 left\n");
}

// What a supervising script reads from `canbridge flash | ...`: stdout to a pipe is block-buffered
// by stdio, so a line not flushed would reach the script only when the command exits. The stream
// here is std::cout's own kind (a stdio_sync_filebuf) over a stdio FILE on a real pipe.
TEST(CliProgress, EachPlainLineReachesAPipeAtOnce) {
  int fds[2];
  ASSERT_EQ(::pipe2(fds, O_CLOEXEC | O_NONBLOCK), 0);
  FILE* const file = ::fdopen(fds[1], "w");  // a pipe: fully buffered, as stdout would be
  ASSERT_NE(file, nullptr);
  __gnu_cxx::stdio_sync_filebuf<char> buffer(file);
  std::ostream out(&buffer);
  ProgressPrinter printer(out, false);
  const auto read_now = [&] {
    std::string got;
    char chunk[512];
    for (ssize_t n; (n = ::read(fds[0], chunk, sizeof chunk)) > 0;) got.append(chunk, n);
    return got;
  };
  const auto t0 = std::chrono::steady_clock::time_point{};
  printer.update({"download", 0, 100000}, t0);
  EXPECT_EQ(read_now(), "download: 0/100000 bytes (0%)\n");
  printer.update({"download", 51200, 100000}, t0 + std::chrono::seconds(2));
  EXPECT_EQ(read_now(), "download: 51200/100000 bytes (51%), 25.0 KiB/s, 0:02 left\n");
  printer.finish();
  ::fclose(file);
  ::close(fds[0]);
}

TEST(CliEndpointAddress, PathsAndHostPorts) {
  EXPECT_FALSE(parse_endpoint("/run/canbridge/surface.sock").tcp);
  EXPECT_FALSE(parse_endpoint("surface.sock").tcp);
  EXPECT_FALSE(parse_endpoint("./a:5").tcp);
  const auto tcp = parse_endpoint("127.0.0.1:5050");
  EXPECT_TRUE(tcp.tcp);
  EXPECT_EQ(tcp.host, "127.0.0.1");
  EXPECT_EQ(tcp.port, "5050");
  const auto v6 = parse_endpoint("[::1]:5050");
  EXPECT_TRUE(v6.tcp);
  EXPECT_EQ(v6.host, "::1");
}

}  // namespace
}  // namespace canbridge::cli
