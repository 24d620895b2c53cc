// Numbered payloads and the delimited bytes between two SessionCores, for the tests that wire
// cores back to back by hand (session_core_test.cpp, session_auth_test.cpp).
#pragma once

#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "backbone/delimited_codec.hpp"

namespace canbridge::backbone::testing {

// Payload `n`: its eight bytes in host order, as the tests' handlers read them back.
inline std::string number(std::uint64_t n) {
  std::string s(8, '\0');
  std::memcpy(s.data(), &n, 8);
  return s;
}

inline std::span<const std::uint8_t> bytes_of(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

// Splits what a core wrote into its envelopes' bytes.
inline std::vector<std::string> split(const std::string& delimited) {
  std::vector<std::string> messages;
  DelimitedDecoder decoder;
  decoder.feed(bytes_of(delimited), [&](std::span<const std::uint8_t> m) {
    messages.emplace_back(reinterpret_cast<const char*>(m.data()), m.size());
  });
  return messages;
}

// The payload numbers first..last, both included.
inline std::vector<std::uint64_t> range(std::uint64_t first, std::uint64_t last) {
  std::vector<std::uint64_t> v;
  for (std::uint64_t n = first; n <= last; ++n) v.push_back(n);
  return v;
}

}  // namespace canbridge::backbone::testing
