// Turns a role's `backbone.auth` block (and a surface's gateways' key files) into the TLS
// handshake its TCP backbone runs: the LinkUpgrade for ClientOptions / ServerOptions.
#pragma once

#include "backbone/link_upgrade.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// The gateway's TLS client: psk proves `name` with the first key of auth.key_file; certificates
// present auth.certificate_file and accept only a surface certificate named auth.surface.
// Empty (plain TCP) in plain mode. Throws std::runtime_error naming the file and the fix when a
// key, certificate or CA cannot be used.
backbone::LinkUpgrade gateway_link_upgrade(const config::GatewayOptions& options);

// The surface's TLS server: psk accepts each configured gateway by the keys in its key_file;
// certificates accept only certificates naming a configured gateway. Empty in plain mode. Throws
// like gateway_link_upgrade.
backbone::LinkUpgrade surface_link_upgrade(const config::SurfaceOptions& options);

}  // namespace canbridge::bridge
