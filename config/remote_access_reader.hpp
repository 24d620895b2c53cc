// Reads the remote access blocks (docs/remote-access.md): the surface's `command_endpoint:` (with
// the TCP clients' tokens, read from their files) and `networks:`, the gateway's `remote:`.
#pragma once

#include <yaml-cpp/yaml.h>

#include <string>

#include "config/options.hpp"
#include "yaml/yaml_reader.hpp"

namespace canbridge::config {

// After the surface's `gateways:` list is read into `out` (networks name their modules).
void read_surface_remote(YamlReader& in, const YAML::Node& root, SurfaceOptions& out);

void read_gateway_remote(YamlReader& in, const YAML::Node& root, bridge::GatewayRemoteOptions& out);

// The first line of a token file that is neither blank nor a '#' comment, trimmed; the file must
// be private like a key file (backbone::check_key_file_permissions, checked on the opened file).
// Empty with `problem` set when it cannot be used.
struct TokenFileResult {
  std::string token;
  std::string problem;
};
TokenFileResult read_token_file(const std::string& path);

}  // namespace canbridge::config
