#include "app/cli_reply.hpp"

#include <charconv>
#include <cstdio>

#include "can/candump_log.hpp"
#include "canopen/ascii_command.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::cli {

namespace {

bool starts_with(std::string_view s, std::string_view prefix) {
  return s.substr(0, prefix.size()) == prefix;
}

std::string_view next_word(std::string_view& rest) {
  std::size_t begin = 0;
  while (begin < rest.size() && rest[begin] == ' ') ++begin;
  std::size_t end = begin;
  while (end < rest.size() && rest[end] != ' ') ++end;
  const std::string_view word = rest.substr(begin, end - begin);
  rest.remove_prefix(end);
  return word;
}

template <typename T>
bool parse_number(std::string_view text, T& value, int base = 10) {
  if (text.empty()) return false;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value, base);
  return ec == std::errc{} && end == text.data() + text.size();
}

}  // namespace

std::optional<std::string_view> answer_to(std::string_view line, unsigned seq) {
  const std::string prefix = "[" + std::to_string(seq) + "]";
  if (!starts_with(line, prefix)) return std::nullopt;
  line.remove_prefix(prefix.size());
  while (!line.empty() && line.front() == ' ') line.remove_prefix(1);
  return line;
}

std::optional<ErrorReply> parse_error(std::string_view rest) {
  if (!starts_with(rest, "ERROR:")) return std::nullopt;
  rest.remove_prefix(6);
  const std::string_view code = next_word(rest);
  ErrorReply e;
  if (starts_with(code, "0x") || starts_with(code, "0X")) {
    e.sdo_abort = true;
    if (!parse_number(code.substr(2), e.code, 16)) return std::nullopt;
  } else if (!parse_number(code, e.code)) {
    return std::nullopt;
  }
  while (!rest.empty() && rest.front() == ' ') rest.remove_prefix(1);
  if (!rest.empty() && rest.front() == '#') rest.remove_prefix(1);
  e.text = std::string(rest);
  return e;
}

int exit_code_for(const ErrorReply& error) {
  if (error.sdo_abort) {
    return error.code == static_cast<std::uint32_t>(canopen::SdoAbort::timeout) ? exit_code::timeout
                                                                                : exit_code::abort;
  }
  if (error.code == static_cast<std::uint32_t>(canopen::AsciiError::outcome_unknown)) {
    return exit_code::outcome_unknown;
  }
  switch (error.code) {
    case 106:  // unsupported net
    case 107:  // unsupported node
      return exit_code::unknown;
    case 103:  // time-out
      return exit_code::timeout;
    case 201:  // lost connection: the node's gateway is not connected
    case 401:  // authentication required
    case 403:  // not permitted for this client's role
      return exit_code::unreachable;
    default:
      return exit_code::abort;
  }
}

std::string describe(const ErrorReply& error) {
  if (error.sdo_abort) {
    // Without the endpoint's text, the category's message, which names the code itself.
    if (error.text.empty()) return "SDO abort: " + canopen::abort_error(error.code).message();
    char code[16];
    std::snprintf(code, sizeof code, "0x%08X", error.code);
    return std::string("SDO abort ") + code + ": " + error.text;
  }
  return "error " + std::to_string(error.code) + ": " + error.text;
}

std::optional<Progress> parse_progress(std::string_view rest) {
  if (next_word(rest) != "PROGRESS") return std::nullopt;
  while (!rest.empty() && rest.back() == ' ') rest.remove_suffix(1);
  // The step may contain spaces: the byte counts are the last two words.
  const std::size_t total_at = rest.rfind(' ');
  if (total_at == std::string_view::npos) return std::nullopt;
  const std::size_t done_at = rest.substr(0, total_at).rfind(' ');
  if (done_at == std::string_view::npos) return std::nullopt;
  Progress p;
  std::string_view step = rest.substr(0, done_at);
  while (!step.empty() && step.front() == ' ') step.remove_prefix(1);
  p.step = std::string(step);
  if (p.step.empty() || !parse_number(rest.substr(done_at + 1, total_at - done_at - 1), p.done) ||
      !parse_number(rest.substr(total_at + 1), p.total)) {
    return std::nullopt;
  }
  return p;
}

std::optional<NodeRow> parse_gateway_state(std::string_view rest) {
  if (next_word(rest) != "gateway") return std::nullopt;
  NodeRow fields;
  for (std::string_view word = next_word(rest); !word.empty(); word = next_word(rest)) {
    const std::size_t eq = word.find('=');
    if (eq == std::string_view::npos) return std::nullopt;
    fields.emplace_back(std::string(word.substr(0, eq)), std::string(word.substr(eq + 1)));
  }
  return fields;
}

std::optional<NodeRow> parse_node_row(std::string_view rest) {
  if (next_word(rest) != "node") return std::nullopt;
  NodeRow row;
  for (std::string_view word = next_word(rest); !word.empty(); word = next_word(rest)) {
    const std::size_t eq = word.find('=');
    if (eq == std::string_view::npos) return std::nullopt;
    row.emplace_back(std::string(word.substr(0, eq)), std::string(word.substr(eq + 1)));
  }
  return row;
}

std::string field(const NodeRow& row, std::string_view key) {
  for (const auto& [k, v] : row) {
    if (k == key) return v;
  }
  return {};
}

std::optional<MonitorFrame> parse_monitor_frame(std::string_view line) {
  if (next_word(line) != "FRAME") return std::nullopt;
  MonitorFrame m;
  std::int64_t us = 0;
  if (!parse_number(next_word(line), us) || !parse_number(next_word(line), m.module)) {
    return std::nullopt;
  }
  const std::string_view dir = next_word(line);
  if (dir != ">" && dir != "<") return std::nullopt;
  m.dir = dir.front();
  auto frame = can::parse_cansend_frame(next_word(line));
  if (!frame || !next_word(line).empty()) return std::nullopt;
  m.frame = frame.value;
  m.frame.timestamp = std::chrono::microseconds(us);
  return m;
}

std::optional<std::uint64_t> parse_dropped(std::string_view line) {
  std::uint64_t n = 0;
  if (next_word(line) != "DROPPED" || !parse_number(next_word(line), n) ||
      !next_word(line).empty()) {
    return std::nullopt;
  }
  return n;
}

}  // namespace canbridge::cli
