// Reads and validates role config files, reporting every problem with file, line and field.
#pragma once

#include <string>
#include <string_view>

#include "config/options.hpp"
#include "yaml/config_error.hpp"

namespace canbridge::config {

GatewayOptions load_gateway(const std::string& path);
SurfaceOptions load_surface(const std::string& path);

// The text of a config file, read within the bounds every config file is read with (a regular
// file of at most 1 MiB; yaml/yaml_reader.hpp); ConfigError naming the file otherwise. For those
// who want the text rather than a role's options: the CLI's -c, the SIGHUP re-read.
std::string read_config_text(const std::string& path);

// Same, from text already in memory; `file` names it in messages.
GatewayOptions parse_gateway(std::string_view yaml, const std::string& file);
SurfaceOptions parse_surface(std::string_view yaml, const std::string& file);

}  // namespace canbridge::config
