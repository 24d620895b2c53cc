#include "app/tls_setup.hpp"

#include <spdlog/spdlog.h>

#include <map>
#include <memory>
#include <stdexcept>

#include "app/key_file_watches.hpp"
#include "backbone/key_file_watch.hpp"
#include "backbone/pre_shared_keys.hpp"
#include "backbone/tls_upgrade.hpp"

namespace canbridge::bridge {

namespace {

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
    case config::AuthMode::psk: {
      auto watch = watch_key_file(auth.key_file, "gateway " + options.name);
      backbone::TlsGatewayPsk psk{options.name, watch->keys(), auth.surface, nullptr};
      psk.current_keys = [watch] { return watch->keys(); };
      return backbone::TlsUpgrade::create(std::move(psk))->link_upgrade();
    }
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
      std::map<std::string, std::shared_ptr<backbone::KeyFileWatch>, std::less<>> watches;
      for (const auto& gateway : options.gateways) {
        auto watch = watch_key_file(gateway.key_file, "gateway " + gateway.name);
        psk.gateways.emplace(gateway.name, watch->keys());
        watches.emplace(gateway.name, std::move(watch));
      }
      psk.current_keys = [watches = std::move(watches)](const std::string& gateway) {
        const auto watch = watches.find(gateway);
        return watch == watches.end() ? std::vector<backbone::PreSharedKey>{}
                                      : watch->second->keys();
      };
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
