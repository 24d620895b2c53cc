// A sender and a receiver to drive any MessageLink from a test: numbered messages queued for the
// link's pull-model source, and a record of what the link delivered and how it ended.
#pragma once

#include <cstdint>
#include <deque>
#include <string>
#include <system_error>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/message_link.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone::testing {

// Message i of a test stream: its index, then a deterministic, variable-length body.
inline std::string numbered(std::uint32_t i) {
  std::string s(4 + i % 300, '\0');
  for (int b = 0; b < 4; ++b) s[static_cast<std::size_t>(b)] = static_cast<char>(i >> (8 * b));
  for (std::size_t k = 4; k < s.size(); ++k) s[k] = static_cast<char>((i * 7 + k) & 0xFF);
  return s;
}

// A sender side: messages queued here go out through the link's pull-model source.
struct Outbox {
  std::deque<std::string> pending;
  int source_calls = 0;
  MessageLink::Source source() {
    return [this](std::string& out) {
      ++source_calls;
      for (const auto& m : pending) append_delimited(out, bytes(m));
      pending.clear();
    };
  }
};

struct Inbox {
  std::vector<std::string> messages;
  int closed_calls = 0;
  std::error_code reason;
  MessageLink::MessageHandler on_message() {
    return [this](std::span<const std::uint8_t> m) { messages.push_back(to_string(m)); };
  }
  MessageLink::ClosedHandler on_closed() {
    return [this](std::error_code ec) {
      ++closed_calls;
      reason = ec;
    };
  }
};

}  // namespace canbridge::backbone::testing
