// Reads who may speak on the backbone: each role's `backbone.auth`, the surface's
// `backbone.admission` and `gateways:` list, and which gateway each surface serial line serves.
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>

#include "config/options.hpp"
#include "yaml/yaml_reader.hpp"

namespace canbridge::config {

// 127.0.0.0/8, ::1 (bracketed or not) and localhost: the only hosts plain operation may use.
bool is_loopback_host(const std::string& host);

// A gateway's `backbone.auth`, after its transport (connect or serial) is read into `out`.
void read_gateway_auth(YamlReader& in, const YAML::Node& root, GatewayOptions& out);

// The surface's `gateways:` list, then its `backbone.auth` (which needs the list: psk keys are
// per gateway), `backbone.admission` and the `gateway:` of each serial line. After the
// transport (listen, serial) is read into `out`.
void read_surface_auth(YamlReader& in, const YAML::Node& root, SurfaceOptions& out);

}  // namespace canbridge::config
