#include "can/candump_log.hpp"

#include <cstdint>
#include <cstdio>
#include <istream>
#include <string>

namespace canbridge::can {

namespace {

constexpr std::uint32_t kErrorFlag = 0x20000000U;  // CAN_ERR_FLAG, as candump prints it
constexpr std::size_t kMaxInterfaceName = 15;      // IFNAMSIZ - 1

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

bool is_blank(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

std::string quoted(std::string_view s) {
  std::string out;
  out.reserve(s.size() + 2);
  out.append(1, '\'').append(s).append(1, '\'');
  return out;
}

// The next blank-separated field of `rest`, consuming it and the blanks before it.
std::string_view next_field(std::string_view& rest) {
  std::size_t begin = 0;
  while (begin < rest.size() && is_blank(rest[begin])) ++begin;
  std::size_t end = begin;
  while (end < rest.size() && !is_blank(rest[end])) ++end;
  std::string_view field = rest.substr(begin, end - begin);
  rest.remove_prefix(end);
  return field;
}

// "(1700000000.123456)" -> nanoseconds since the epoch.
Parsed<std::chrono::nanoseconds> parse_timestamp(std::string_view text) {
  Parsed<std::chrono::nanoseconds> r;
  const std::string expected = "timestamp " + quoted(text) + " is not (seconds.fraction)";
  if (text.size() < 5 || text.front() != '(' || text.back() != ')') {
    r.error = expected;
    return r;
  }
  text = text.substr(1, text.size() - 2);
  const std::size_t dot = text.find('.');
  if (dot == std::string_view::npos || dot == 0 || dot + 1 == text.size()) {
    r.error = expected;
    return r;
  }
  const std::string_view secs = text.substr(0, dot);
  const std::string_view frac = text.substr(dot + 1);
  if (secs.size() > 12 || frac.size() > 9) {
    r.error = "timestamp " + quoted(text) + " has too many digits";
    return r;
  }
  std::int64_t s = 0;
  for (char c : secs) {
    if (c < '0' || c > '9') {
      r.error = expected;
      return r;
    }
    s = s * 10 + (c - '0');
  }
  std::int64_t ns = 0;
  for (std::size_t i = 0; i < 9; ++i) {
    const char c = i < frac.size() ? frac[i] : '0';
    if (c < '0' || c > '9') {
      r.error = expected;
      return r;
    }
    ns = ns * 10 + (c - '0');
  }
  r.value = std::chrono::seconds(s) + std::chrono::nanoseconds(ns);
  return r;
}

// The identifier before '#': 3 hex digits standard, 8 extended (or an error frame's class bits
// with the error flag). Sets the frame's id and flags; returns the error, empty when valid.
std::string parse_identifier(std::string_view id_text, Frame& f) {
  if (id_text.size() != 3 && id_text.size() != 8) {
    return "identifier " + quoted(id_text) +
           " must be 3 (standard) or 8 (extended) hex digits, not " +
           std::to_string(id_text.size());
  }
  std::uint32_t id = 0;
  for (char c : id_text) {
    const int v = hex_value(c);
    if (v < 0) return "identifier " + quoted(id_text) + " is not hexadecimal";
    id = (id << 4) | static_cast<std::uint32_t>(v);
  }
  if (id_text.size() == 3) {
    if (id > kMaxStandardId) return "standard identifier " + quoted(id_text) + " is above 7FF";
  } else if ((id & ~kMaxExtendedId) == kErrorFlag) {
    f.flags = FrameFlags::error;
    id &= kMaxExtendedId;
  } else if (id > kMaxExtendedId) {
    return "extended identifier " + quoted(id_text) + " is above 1FFFFFFF";
  } else {
    f.flags = FrameFlags::extended;
  }
  f.id = id;
  return {};
}

// "R" or "R<len>" after the '#' (the 'R' already removed): a remote frame, no data bytes.
std::string parse_remote(std::string_view data, Frame& f) {
  if (f.is_error()) return "an error frame cannot be a remote frame";
  f.flags |= FrameFlags::remote;
  if (data.empty()) return {};
  if (data.size() != 1 || data.front() < '0' || data.front() > '8') {
    return "remote frame length " + quoted(data) + " is not a single digit 0..8";
  }
  f.len = static_cast<std::uint8_t>(data.front() - '0');
  return {};
}

// Up to 8 bytes of two hex digits each, optionally separated by '.'.
std::string parse_data_bytes(std::string_view data, Frame& f) {
  std::size_t pos = 0;
  std::size_t len = 0;
  while (pos < data.size()) {
    if (data[pos] == '.') ++pos;  // an optional separator before each byte
    if (pos == data.size()) break;
    if (len == kMaxPayload) return "data " + quoted(data) + " has more than 8 bytes";
    if (pos + 1 == data.size()) return "data " + quoted(data) + " ends in half a byte";
    const int hi = hex_value(data[pos]);
    const int lo = hex_value(data[pos + 1]);
    if (hi < 0 || lo < 0) {
      return "data " + quoted(data) + " has a character that is not hex at offset " +
             std::to_string(pos + (hi < 0 ? 0 : 1));
    }
    f.data[len++] = static_cast<std::uint8_t>((hi << 4) | lo);
    pos += 2;
  }
  f.len = static_cast<std::uint8_t>(len);
  return {};
}

}  // namespace

Parsed<Frame> parse_cansend_frame(std::string_view text) {
  Parsed<Frame> r;
  const std::size_t hash = text.find('#');
  if (hash == std::string_view::npos) {
    r.error = "frame " + quoted(text) + " has no '#' between identifier and data";
    return r;
  }
  r.error = parse_identifier(text.substr(0, hash), r.value);
  if (!r.error.empty()) return r;
  std::string_view data = text.substr(hash + 1);
  if (!data.empty() && data.front() == '#') {
    r.error = "CAN FD frames ('##') are not supported";
  } else if (!data.empty() && (data.front() == 'R' || data.front() == 'r')) {
    r.error = parse_remote(data.substr(1), r.value);
  } else {
    r.error = parse_data_bytes(data, r.value);
  }
  return r;
}

std::string format_cansend_frame(const Frame& frame) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  char buf[32];
  int n = 0;
  if (frame.is_error()) {
    n = std::snprintf(buf, sizeof buf, "%08X#", (frame.id & kMaxExtendedId) | kErrorFlag);
  } else if (frame.is_extended()) {
    n = std::snprintf(buf, sizeof buf, "%08X#", frame.id & kMaxExtendedId);
  } else {
    n = std::snprintf(buf, sizeof buf, "%03X#", frame.id & kMaxStandardId);
  }
  std::string s(buf, static_cast<std::size_t>(n));
  const std::size_t len = std::min<std::size_t>(frame.len, kMaxPayload);
  if (frame.is_remote() && !frame.is_error()) {
    s += 'R';
    if (len != 0) s += static_cast<char>('0' + len);
    return s;
  }
  for (std::size_t i = 0; i < len; ++i) {
    s += kHex[frame.data[i] >> 4];
    s += kHex[frame.data[i] & 0x0F];
  }
  return s;
}

Parsed<CandumpRecord> parse_candump_line(std::string_view line) {
  Parsed<CandumpRecord> r;
  std::string_view rest = line;
  const std::string_view stamp = next_field(rest);
  const std::string_view interface = next_field(rest);
  const std::string_view frame = next_field(rest);
  if (stamp.empty()) {
    r.error = "empty line";
    return r;
  }
  if (frame.empty()) {
    r.error = "line " + quoted(line) + " lacks fields: expected '(timestamp) interface frame'";
    return r;
  }
  if (!next_field(rest).empty()) {
    r.error = "unexpected text after the frame in " + quoted(line);
    return r;
  }
  auto time = parse_timestamp(stamp);
  if (!time) {
    r.error = time.error;
    return r;
  }
  if (interface.size() > kMaxInterfaceName) {
    r.error = "interface name " + quoted(interface) + " is longer than 15 characters";
    return r;
  }
  auto parsed = parse_cansend_frame(frame);
  if (!parsed) {
    r.error = parsed.error;
    return r;
  }
  r.value.interface = std::string(interface);
  r.value.frame = parsed.value;
  r.value.frame.timestamp = time.value;
  return r;
}

std::string format_candump_line(const Frame& frame, std::string_view interface) {
  const auto us = std::chrono::duration_cast<std::chrono::microseconds>(frame.timestamp).count();
  const long long t = us < 0 ? 0 : us;
  char buf[48];
  const int n = std::snprintf(buf, sizeof buf, "(%010lld.%06lld) ", t / 1'000'000, t % 1'000'000);
  std::string s(buf, static_cast<std::size_t>(n));
  s += interface;
  s += ' ';
  s += format_cansend_frame(frame);
  return s;
}

std::string read_candump_log(std::istream& in, std::vector<CandumpRecord>& out) {
  std::string line;
  std::size_t number = 0;
  while (std::getline(in, line)) {
    ++number;
    bool blank = true;
    for (char c : line) blank = blank && is_blank(c);
    if (blank) continue;
    auto parsed = parse_candump_line(line);
    if (!parsed) return "line " + std::to_string(number) + ": " + parsed.error;
    out.push_back(std::move(parsed.value));
  }
  return {};
}

}  // namespace canbridge::can
