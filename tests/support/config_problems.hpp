// Assertions on configuration errors, shared by the role-config and rig-file tests: catch the
// ConfigError a load throws and look for one problem by line, field and message text.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "yaml/config_error.hpp"

namespace canbridge::test {

// The problems `load()` throws; a test failure (and none) when it throws nothing.
std::vector<config::ConfigProblem> problems_of(auto&& load) {
  try {
    load();
  } catch (const config::ConfigError& e) {
    return e.problems();
  }
  ADD_FAILURE() << "expected a ConfigError";
  return {};
}

// True when a problem has this field, contains `text`, and sits on `line` (0: any line).
inline bool has(const std::vector<config::ConfigProblem>& ps, int line, const std::string& field,
                const std::string& text) {
  return std::any_of(ps.begin(), ps.end(), [&](const config::ConfigProblem& p) {
    return (line == 0 || p.line == line) && p.field == field &&
           p.message.find(text) != std::string::npos;
  });
}

// One problem per line, for failure messages.
inline std::string dump(const std::vector<config::ConfigProblem>& ps) {
  std::string s;
  for (const auto& p : ps) s += p.to_string() + "\n";
  return s;
}

}  // namespace canbridge::test
