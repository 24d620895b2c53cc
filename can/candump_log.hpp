// Reads and writes can-utils' candump log format, "(1700000000.123456) can0 181#0102", and the
// cansend frame syntax inside it, so tests and tools can exchange frames with can-utils.
#pragma once

#include <iosfwd>
#include <string>
#include <string_view>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::can {

// A parsed value, or the reason the text was rejected (parsing never throws).
template <typename T>
struct Parsed {
  T value{};
  std::string error;  // empty on success
  explicit operator bool() const { return error.empty(); }
};

// One log line. frame.timestamp carries the logged time (microsecond resolution).
struct CandumpRecord {
  std::string interface;
  Frame frame;
};

// cansend syntax, as can-utils 2020.11 reads it:
//   3 hex digits: standard id (<= 7FF); 8 hex digits: extended id (<= 1FFFFFFF), or an error
//   frame when bit 29 (CAN_ERR_FLAG, 0x20000000) is set: the id then holds the CAN_ERR_* class
//   bits, exactly as candump prints error frames ("20000004#0004000000000000");
//   "#R" or "#R<0..8>": remote frame with that DLC; otherwise 0..8 data bytes as hex pairs,
//   optionally separated by '.'. CAN FD ("##") is rejected.
Parsed<Frame> parse_cansend_frame(std::string_view text);

// The frame as candump -L writes it: upper-case hex, no '.' separators, "R<dlc>" for remote
// frames with a nonzero DLC, error frames as 8 digits including CAN_ERR_FLAG.
std::string format_cansend_frame(const Frame& frame);

// "(seconds.fraction) interface frame"; fields may be separated by several blanks (candump pads
// interface names when it listens on several) and trailing blanks or CR are ignored.
Parsed<CandumpRecord> parse_candump_line(std::string_view line);

// Exactly what candump -L prints for the frame (without the newline): the timestamp as
// %010ld.%06ld of frame.timestamp, truncated to microseconds (negative times are written as 0).
std::string format_candump_line(const Frame& frame, std::string_view interface);

// Appends every record of a log to `out`, skipping blank lines. Stops at the first malformed
// line and returns "line N: reason"; empty when the whole stream was read.
std::string read_candump_log(std::istream& in, std::vector<CandumpRecord>& out);

}  // namespace canbridge::can
