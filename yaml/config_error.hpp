// The one error model of startup configuration: every problem of a file, each with file, line
// and dotted field, thrown together so an operator fixes them in one pass.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace canbridge::config {

struct ConfigProblem {
  std::string file;
  int line = 0;       // 1-based; 0 when the problem is about the whole file
  std::string field;  // dotted path, e.g. modules[1].nodes.5
  std::string message;
  std::string to_string() const;
};

// Thrown at startup only; what() lists every problem, one per line.
class ConfigError : public std::runtime_error {
 public:
  explicit ConfigError(std::vector<ConfigProblem> problems);
  const std::vector<ConfigProblem>& problems() const { return problems_; }

 private:
  std::vector<ConfigProblem> problems_;
};

}  // namespace canbridge::config
