#include "app/cli_cmd.hpp"

#include <charconv>
#include <istream>
#include <ostream>

#include "app/cli_reply.hpp"

namespace canbridge::cli {

namespace {

std::string_view trimmed(std::string_view text) {
  while (!text.empty() && (text.front() == ' ' || text.front() == '\t')) text.remove_prefix(1);
  while (!text.empty() && (text.back() == ' ' || text.back() == '\t')) text.remove_suffix(1);
  return text;
}

// Nothing for the endpoint to do: cocomm's input files carry comments and blank lines.
bool nothing_to_send(std::string_view line) {
  line = trimmed(line);
  return line.empty() || line.front() == '#';
}

// Intermediate lines of an answer that has more to come: a node row, a gateway's state (nodes)
// or a flash progress line.
bool more_to_come(std::string_view rest) {
  return parse_node_row(rest) || parse_gateway_state(rest) || parse_progress(rest);
}

class RawLines {
 public:
  explicit RawLines(Session& session) : s_(session) {}

  // Sends one line and prints its answer; false when the endpoint stopped answering (`exit_`
  // then says why).
  bool send(std::string_view text, std::size_t place) {
    std::string line(trimmed(text));
    long long seq = line_sequence(line);
    // As cocomm: a line that does not start with '[' gets a sequence number; one that does is
    // sent as it is (the endpoint answers a malformed one with an unnumbered error).
    if (line.front() != '[') {
      seq = static_cast<long long>(place);
      line = "[" + std::to_string(place) + "] " + line;
    }
    if (const auto ec = s_.connection().send_line(line)) {
      exit_ = s_.report_read_error(ec);
      return false;
    }
    for (;;) {
      std::string answer;
      if (const auto ec = s_.connection().read_line(answer, s_.timeout())) {
        exit_ = s_.report_read_error(ec);
        return false;
      }
      s_.io().out << answer << "\n";
      std::optional<std::string_view> rest;
      if (seq >= 0) rest = answer_to(answer, static_cast<unsigned>(seq));
      if (!rest) {
        // An unnumbered error is the endpoint's refusal of the line itself (a malformed
        // sequence, 401 before auth); other lines are help's inner lines, monitor frames or
        // another request's: printed, and the answer still to come.
        if (const auto error = parse_error(answer)) return note(*error);
        continue;
      }
      if (const auto error = parse_error(*rest)) return note(*error);
      if (!more_to_come(*rest)) return true;
    }
  }

  // 0, the first error's code, or the failure that stopped the run.
  int exit() const { return exit_; }

 private:
  bool note(const ErrorReply& error) {
    if (exit_ == exit_code::ok) exit_ = exit_code_for(error);
    return true;
  }

  Session& s_;
  int exit_ = exit_code::ok;
};

}  // namespace

long long line_sequence(std::string_view line) {
  line = trimmed(line);
  const std::size_t close = line.find(']');
  if (line.empty() || line.front() != '[' || close == std::string_view::npos || close < 2) {
    return -1;
  }
  unsigned long long value = 0;
  const auto [end, ec] = std::from_chars(line.data() + 1, line.data() + close, value);
  if (ec != std::errc{} || end != line.data() + close || value > 0xFFFFFFFFull) return -1;
  return static_cast<long long>(value);
}

int run_cmd(const Connect& connect, const std::vector<std::string>& lines, std::istream& in) {
  for (const std::string& line : lines) {
    // One argument, one request: a line break inside it would be a second request whose answer
    // this command would not wait for.
    if (line.find_first_of("\r\n") != std::string::npos) {
      throw UsageError{"a line contains a line break: give each request as its own argument"};
    }
    if (nothing_to_send(line)) {
      throw UsageError{"an empty or comment-only line: nothing to send"};
    }
  }
  int rc = exit_code::ok;
  const auto session = connect(rc);
  if (!session) return rc;
  RawLines raw(*session);
  if (!lines.empty()) {
    for (std::size_t i = 0; i < lines.size(); ++i) {
      if (!raw.send(lines[i], i + 1)) break;
    }
    return raw.exit();
  }
  std::size_t place = 0;
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    ++place;
    if (nothing_to_send(line)) continue;
    if (!raw.send(line, place)) break;
  }
  return raw.exit();
}

}  // namespace canbridge::cli
