#include "yaml/config_error.hpp"

namespace canbridge::config {

std::string ConfigProblem::to_string() const {
  std::string s = file;
  if (line > 0) s.append(":").append(std::to_string(line));
  s += ": ";
  if (!field.empty()) s += field + ": ";
  return s + message;
}

namespace {

std::string join(const std::vector<ConfigProblem>& problems) {
  std::string s = "invalid configuration (" + std::to_string(problems.size()) + " problem" +
                  (problems.size() == 1 ? "" : "s") + ")";
  for (const auto& p : problems) s += "\n  " + p.to_string();
  return s;
}

}  // namespace

ConfigError::ConfigError(std::vector<ConfigProblem> problems)
    : std::runtime_error(join(problems)), problems_(std::move(problems)) {}

}  // namespace canbridge::config
