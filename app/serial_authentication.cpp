#include "app/serial_authentication.hpp"

#include <map>
#include <memory>
#include <stdexcept>
#include <string>

#include "backbone/pre_shared_keys.hpp"

namespace canbridge::bridge {

namespace {

std::vector<backbone::PreSharedKey> load_keys(const std::string& key_file, const std::string& who) {
  if (key_file.empty()) {
    throw std::runtime_error(who + ": serial backbone authentication needs a key_file");
  }
  backbone::KeyFileResult loaded = backbone::load_key_file(key_file);
  if (!loaded) throw std::runtime_error(who + ": " + loaded.problem->message);
  return std::move(loaded.keys);
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
  o.keys = load_keys(options.auth.key_file, "gateway " + options.name);
  o.tag_size = options.auth.mac_tag_bytes;
  return [o = checked(std::move(o))](const std::string&) {
    return std::make_unique<backbone::PeerAuthenticator>(o);
  };
}

SessionAuthenticatorFactory serial_authenticators(const config::SurfaceOptions& options) {
  if (options.auth.mode == config::AuthMode::plain || options.serial.empty()) return nullptr;
  std::map<std::string, backbone::PeerAuthenticatorOptions> by_device;
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
    o.keys = load_keys(gateway->key_file, "gateway " + gateway->name);
    o.tag_size = options.auth.mac_tag_bytes;
    by_device.emplace(line.device, checked(std::move(o)));
  }
  return [by_device = std::move(by_device)](
             const std::string& link_name) -> std::unique_ptr<backbone::PeerAuthenticator> {
    const auto line = by_device.find(link_name);
    if (line == by_device.end()) return nullptr;  // a TCP link: TLS proves its peer
    return std::make_unique<backbone::PeerAuthenticator>(line->second);
  };
}

}  // namespace canbridge::bridge
