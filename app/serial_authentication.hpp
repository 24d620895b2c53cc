// Which serial backbone lines the session authenticates and with which keys (docs/security.md,
// "Serial lines"), built once at startup from a role's validated options.
#pragma once

#include "backbone/peer_stream.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

using SessionAuthenticatorFactory = decltype(backbone::SessionOptions::authenticator);

// The gateway's serial line: its key file, its name, the configured surface identity. Empty in
// plain mode and on TCP (TLS authenticates there). Throws std::runtime_error naming the key file
// and what is wrong with it.
SessionAuthenticatorFactory serial_authenticator(const config::GatewayOptions& options);

// The surface's serial lines, each with the key of the gateway configured for it
// (SerialLineOptions::gateway); links that are not one of those lines (TCP) get none. Empty in
// plain mode. Throws std::runtime_error for a line without a usable gateway key.
SessionAuthenticatorFactory serial_authenticators(const config::SurfaceOptions& options);

}  // namespace canbridge::bridge
