#include "app/serial_authentication.hpp"

#include <map>
#include <memory>
#include <stdexcept>
#include <string>

#include "app/key_file_watches.hpp"
#include "backbone/key_file_watch.hpp"
#include "backbone/pre_shared_keys.hpp"

namespace canbridge::bridge {

namespace {

// One link's authenticator options: `o` with the watched file's current keys.
backbone::PeerAuthenticatorOptions with_current_keys(backbone::PeerAuthenticatorOptions o,
                                                     backbone::KeyFileWatch& watch) {
  o.keys = watch.keys();
  return o;
}

// Checks the options once (identities, tag size) so that a mistake stops the start, not a link.
backbone::PeerAuthenticatorOptions checked(backbone::PeerAuthenticatorOptions o) {
  try {
    backbone::PeerAuthenticator probe(o);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error("serial backbone authentication: " + std::string(e.what()));
  }
  return o;
}

}  // namespace

SessionAuthenticatorFactory serial_authenticator(const config::GatewayOptions& options) {
  if (options.auth.mode == config::AuthMode::plain || !options.serial) return nullptr;
  backbone::PeerAuthenticatorOptions o;
  o.role = backbone::AuthRole::gateway;
  o.own_identity = options.name;
  o.peer_identity = options.auth.surface;
  auto watch = watch_key_file(options.auth.key_file, "gateway " + options.name);
  o.keys = watch->keys();
  o.tag_size = options.auth.mac_tag_bytes;
  return [o = checked(std::move(o)), watch](const std::string&) {
    return std::make_unique<backbone::PeerAuthenticator>(with_current_keys(o, *watch));
  };
}

SessionAuthenticatorFactory serial_authenticators(const config::SurfaceOptions& options) {
  if (options.auth.mode == config::AuthMode::plain || options.serial.empty()) return nullptr;
  struct Line {
    backbone::PeerAuthenticatorOptions options;
    std::shared_ptr<backbone::KeyFileWatch> keys;
  };
  std::map<std::string, Line> by_device;
  for (const config::SerialLineOptions& line : options.serial) {
    const config::AcceptedGatewayOptions* gateway = nullptr;
    for (const auto& g : options.gateways) {
      if (g.name == line.gateway) gateway = &g;
    }
    if (!gateway) {
      throw std::runtime_error("serial line " + line.device + ": gateway '" + line.gateway +
                               "' is not one of the configured gateways");
    }
    backbone::PeerAuthenticatorOptions o;
    o.role = backbone::AuthRole::surface;
    o.own_identity = options.name;
    o.peer_identity = gateway->name;
    auto watch = watch_key_file(gateway->key_file, "gateway " + gateway->name);
    o.keys = watch->keys();
    o.tag_size = options.auth.mac_tag_bytes;
    by_device.emplace(line.device, Line{checked(std::move(o)), std::move(watch)});
  }
  return [by_device = std::move(by_device)](
             const std::string& link_name) -> std::unique_ptr<backbone::PeerAuthenticator> {
    const auto line = by_device.find(link_name);
    if (line == by_device.end()) return nullptr;  // a TCP link: TLS proves its peer
    return std::make_unique<backbone::PeerAuthenticator>(
        with_current_keys(line->second.options, *line->second.keys));
  };
}

}  // namespace canbridge::bridge
