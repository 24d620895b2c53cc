// Reads and validates role config files, reporting every problem with file, line and field.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "config/options.hpp"

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

GatewayOptions load_gateway(const std::string& path);
SurfaceOptions load_surface(const std::string& path);

// Same, from text already in memory; `file` names it in messages.
GatewayOptions parse_gateway(std::string_view yaml, const std::string& file);
SurfaceOptions parse_surface(std::string_view yaml, const std::string& file);

}  // namespace canbridge::config
