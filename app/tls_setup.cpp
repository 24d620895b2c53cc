#include "app/tls_setup.hpp"

#include <spdlog/spdlog.h>

#include <stdexcept>

#include "backbone/pre_shared_keys.hpp"
#include "backbone/tls_upgrade.hpp"

namespace canbridge::bridge {

namespace {

std::vector<backbone::PreSharedKey> load_keys(const std::string& file, const std::string& whose) {
  if (file.empty()) {
    throw std::runtime_error("backbone.auth psk: no key_file for " + whose +
                             " (make one with `openssl rand -hex 32`, see docs/security.md)");
  }
  backbone::KeyFileResult result = backbone::load_key_file(file);
  if (!result) throw std::runtime_error(result.problem->message);
  return std::move(result.keys);
}

backbone::TlsCertificates certificates(const config::AuthOptions& auth, bool server,
                                       std::vector<std::string> accepted) {
  backbone::TlsCertificates c;
  c.server = server;
  c.certificate_file = auth.certificate_file;
  c.private_key_file = auth.private_key_file;
  c.ca_file = auth.ca_file;
  c.accepted_names = std::move(accepted);
  return c;
}

}  // namespace

backbone::LinkUpgrade gateway_link_upgrade(const config::GatewayOptions& options) {
  const config::AuthOptions& auth = options.auth;
  switch (auth.mode) {
    case config::AuthMode::plain:
      return {};
    case config::AuthMode::psk:
      return backbone::TlsUpgrade::create(
                 backbone::TlsGatewayPsk{options.name,
                                         load_keys(auth.key_file, "gateway " + options.name),
                                         auth.surface})
          ->link_upgrade();
    case config::AuthMode::certificates:
      return backbone::TlsUpgrade::create(certificates(auth, false, {auth.surface}))
          ->link_upgrade();
  }
  return {};
}

backbone::LinkUpgrade surface_link_upgrade(const config::SurfaceOptions& options) {
  const config::AuthOptions& auth = options.auth;
  switch (auth.mode) {
    case config::AuthMode::plain:
      return {};
    case config::AuthMode::psk: {
      backbone::TlsSurfacePsk psk;
      for (const auto& gateway : options.gateways) {
        psk.gateways.emplace(gateway.name, load_keys(gateway.key_file, "gateway " + gateway.name));
      }
      return backbone::TlsUpgrade::create(std::move(psk))->link_upgrade();
    }
    case config::AuthMode::certificates: {
      std::vector<std::string> names;
      for (const auto& gateway : options.gateways) names.push_back(gateway.name);
      return backbone::TlsUpgrade::create(certificates(auth, true, std::move(names)))
          ->link_upgrade();
    }
  }
  return {};
}

}  // namespace canbridge::bridge
