#include "can/candump_log.hpp"

#include <gtest/gtest.h>

#include <sstream>

namespace canbridge::can {
namespace {

using namespace std::chrono_literals;

Frame remote(std::uint32_t id, std::uint8_t extra_flags, std::uint8_t dlc) {
  Frame f;
  f.id = id;
  f.flags = static_cast<std::uint8_t>(FrameFlags::remote | extra_flags);
  f.len = dlc;
  return f;
}

// Lines exactly as candump -L (can-utils 2020.11) printed them in the vcan rig.
struct Case {
  const char* line;
  Frame frame;
};

TEST(CandumpLog, ParsesAndFormatsWhatCandumpPrints) {
  const Case cases[] = {
      {"(1795317925.521798) vcan0 123#DEADBEEF", Frame::make(0x123, 0, {0xDE, 0xAD, 0xBE, 0xEF})},
      {"(1795317925.561581) vcan0 12345678#01", Frame::make(0x12345678, FrameFlags::extended, {1})},
      {"(1795317925.598677) vcan0 7FF#R", remote(0x7FF, 0, 0)},
      {"(1795317925.635128) vcan0 7FF#R3", remote(0x7FF, 0, 3)},
      {"(1795317925.671956) vcan0 100#", Frame::make(0x100, 0, {})},
      {"(1795317925.707685) vcan0 00000001#R", remote(1, FrameFlags::extended, 0)},
      {"(1795318459.581371) vcan0 123#R8", remote(0x123, 0, 8)},
      {"(1795317925.743269) vcan0 1FFFFFFF#1122334455667788",
       Frame::make(0x1FFFFFFF, FrameFlags::extended,
                   {0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88})},
      {"(1795318459.432384) vcan0 20000004#0004000000000000",
       Frame::make(0x4, FrameFlags::error, {0, 4, 0, 0, 0, 0, 0, 0})},
      {"(1795318459.475057) vcan0 20000040#", Frame::make(0x40, FrameFlags::error, {})},
      {"(0000000012.000001) can1 000#00", Frame::make(0, 0, {0})},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.line);
    auto parsed = parse_candump_line(c.line);
    ASSERT_TRUE(parsed) << parsed.error;
    EXPECT_EQ(parsed.value.frame, c.frame);
    EXPECT_EQ(parsed.value.frame.flags, c.frame.flags);
    EXPECT_EQ(format_candump_line(parsed.value.frame, parsed.value.interface), c.line);
  }
}

TEST(CandumpLog, TimestampAndInterface) {
  auto parsed = parse_candump_line("(1700000000.123456) can0 181#0102");
  ASSERT_TRUE(parsed) << parsed.error;
  EXPECT_EQ(parsed.value.interface, "can0");
  EXPECT_EQ(parsed.value.frame.timestamp, 1700000000s + 123456us);
  EXPECT_EQ(parsed.value.frame, Frame::standard(0x181, {1, 2}));

  Frame f = Frame::standard(0x181, {1, 2});
  f.timestamp = 1700000000s + 123456789ns;  // sub-microsecond digits are truncated
  EXPECT_EQ(format_candump_line(f, "can0"), "(1700000000.123456) can0 181#0102");
  f.timestamp = 5s;
  EXPECT_EQ(format_candump_line(f, "can0"), "(0000000005.000000) can0 181#0102");
  f.timestamp = -1s;
  EXPECT_EQ(format_candump_line(f, "can0"), "(0000000000.000000) can0 181#0102");
}

TEST(CandumpLog, AcceptsWhatCansendAcceptsBeyondCandumpOutput) {
  // Dots between bytes, lower-case hex, candump's padding of short interface names, a CR.
  auto p = parse_candump_line("(1.5)   vcan0  5a1#11.2233.44556677.88\r");
  ASSERT_TRUE(p) << p.error;
  EXPECT_EQ(p.value.frame, Frame::make(0x5A1, 0, {0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88}));
  EXPECT_EQ(p.value.frame.timestamp, 1500ms);
  EXPECT_EQ(format_cansend_frame(p.value.frame), "5A1#1122334455667788");

  auto r = parse_cansend_frame("00000123#r0");
  ASSERT_TRUE(r) << r.error;
  EXPECT_EQ(r.value, remote(0x123, FrameFlags::extended, 0));
  EXPECT_EQ(format_cansend_frame(r.value), "00000123#R");
  auto trailing_dot = parse_cansend_frame("123#11.");
  ASSERT_TRUE(trailing_dot) << trailing_dot.error;
  EXPECT_EQ(trailing_dot.value, Frame::make(0x123, 0, {0x11}));
}

TEST(CandumpLog, RoundTripsEveryKindOfFrame) {
  std::vector<Frame> frames;
  for (std::uint8_t len = 0; len <= kMaxPayload; ++len) {
    std::array<std::uint8_t, 8> bytes{};
    for (std::uint8_t i = 0; i < len; ++i) bytes[i] = static_cast<std::uint8_t>(0xA0 + i * 7);
    frames.push_back(Frame::from_span(0x7FF - len, {bytes.data(), len}));
    frames.push_back(
        Frame::from_span(0x1ABCDE00u + len, {bytes.data(), len}, FrameFlags::extended));
    frames.push_back(remote(len, 0, len));
    frames.push_back(remote(0x10000 + len, FrameFlags::extended, len));
  }
  frames.push_back(Frame::make(0x1FFFFFFF, FrameFlags::error, {1, 2, 3, 4, 5, 6, 7, 8}));
  std::stringstream log;
  std::int64_t us = 1'700'000'000'000'000;
  for (Frame& f : frames) {
    f.timestamp = std::chrono::microseconds(us += 1234);
    log << format_candump_line(f, "vcan7") << '\n';
  }
  log << "\n";  // a blank line is skipped
  std::vector<CandumpRecord> read;
  EXPECT_EQ(read_candump_log(log, read), "");
  ASSERT_EQ(read.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    SCOPED_TRACE(format_cansend_frame(frames[i]));
    EXPECT_EQ(read[i].frame, frames[i]);
    EXPECT_EQ(read[i].frame.flags, frames[i].flags);
    EXPECT_EQ(read[i].frame.timestamp, frames[i].timestamp);
    EXPECT_EQ(read[i].interface, "vcan7");
  }
}

TEST(CandumpLog, RejectsMalformedLinesWithAReason) {
  const std::pair<const char*, const char*> bad[] = {
      {"", "empty line"},
      {"(1700000000.123456) can0", "lacks fields"},
      {"(1700000000.123456)", "lacks fields"},
      {"1700000000.123456 can0 123#00", "is not (seconds.fraction)"},
      {"(1700000000) can0 123#00", "is not (seconds.fraction)"},
      {"(17000x0000.123456) can0 123#00", "is not (seconds.fraction)"},
      {"(1700000000.1234567890) can0 123#00", "too many digits"},
      {"(1.0) can0 123#00 extra", "unexpected text"},
      {"(1.0) averyveryverylongname 123#00", "longer than 15"},
      {"(1.0) can0 12300", "no '#'"},
      {"(1.0) can0 12#00", "must be 3 (standard) or 8 (extended)"},
      {"(1.0) can0 1234#00", "must be 3 (standard) or 8 (extended)"},
      {"(1.0) can0 12G#00", "not hexadecimal"},
      {"(1.0) can0 800#00", "above 7FF"},
      {"(1.0) can0 40000000#00", "above 1FFFFFFF"},
      {"(1.0) can0 123#0", "half a byte"},
      {"(1.0) can0 123#0011223", "half a byte"},
      {"(1.0) can0 123#ZZ", "not hex"},
      {"(1.0) can0 123#00..11", "not hex"},
      {"(1.0) can0 123#001122334455667788", "more than 8 bytes"},
      {"(1.0) can0 123#R9", "not a single digit 0..8"},
      {"(1.0) can0 123#R12", "not a single digit 0..8"},
      {"(1.0) can0 20000004#R", "cannot be a remote"},
      {"(1.0) can0 123##1", "CAN FD"},
  };
  for (const auto& [line, reason] : bad) {
    SCOPED_TRACE(line);
    auto parsed = parse_candump_line(line);
    EXPECT_FALSE(parsed);
    EXPECT_NE(parsed.error.find(reason), std::string::npos) << parsed.error;
  }
}

TEST(CandumpLog, ReadReportsTheLineNumberOfTheFirstBadLine) {
  std::istringstream log(
      "(1.000000) can0 123#00\n"
      "(2.000000) can0 124#01\n"
      "(3.000000) can0 125#0\n"
      "(4.000000) can0 126#02\n");
  std::vector<CandumpRecord> read;
  const std::string error = read_candump_log(log, read);
  EXPECT_EQ(error.rfind("line 3: ", 0), 0u) << error;
  EXPECT_EQ(read.size(), 2u);
}

}  // namespace
}  // namespace canbridge::can
