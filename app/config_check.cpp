#include "app/config_check.hpp"

#include <algorithm>
#include <exception>
#include <optional>

#include "app/tls_setup.hpp"
#include "config/loader.hpp"

namespace canbridge::bridge {

namespace {

// The loader reports a file written for the other role as a problem of field `role` (and then
// names nothing else): that is the one failure after which the other role's reader is tried.
bool wrong_role(const config::ConfigError& e) {
  return std::any_of(e.problems().begin(), e.problems().end(),
                     [](const config::ConfigProblem& p) { return p.field == "role"; });
}

std::string auth_mode(config::AuthMode mode) {
  switch (mode) {
    case config::AuthMode::plain:
      return "plain";
    case config::AuthMode::psk:
      return "psk";
    case config::AuthMode::certificates:
      return "certificates";
  }
  return "?";
}

std::string check_gateway(const config::GatewayOptions& options) {
  // Keys and certificates as the role loads them at start; throws naming the file and the fix.
  (void)gateway_link_upgrade(options);
  std::string buses;
  for (const auto& m : options.modules) {
    if (!buses.empty()) buses += ", ";
    buses += "module " + std::to_string(m.id) + " on " + m.bus;
  }
  return "gateway " + options.name + ": " + std::to_string(options.modules.size()) +
         " module(s) (" + buses + "), auth " + auth_mode(options.auth.mode);
}

std::string check_surface(const config::SurfaceOptions& options) {
  (void)surface_link_upgrade(options);
  return "surface " + options.name + ": bus " + options.bus + ", " +
         std::to_string(options.gateways.size()) + " gateway(s), auth " +
         auth_mode(options.auth.mode);
}

}  // namespace

int check_config(const std::string& path, std::ostream& out, std::ostream& err) {
  try {
    std::string summary;
    try {
      summary = check_gateway(config::load_gateway(path));
    } catch (const config::ConfigError& e) {
      if (!wrong_role(e)) throw;
      summary = check_surface(config::load_surface(path));
    }
    out << path << ": valid, " << summary << "\n";
    return 0;
  } catch (const config::ConfigError& e) {
    err << "canbridge: " << e.what() << "\n";
  } catch (const std::exception& e) {
    err << "canbridge: " << path << ": " << e.what() << "\n";
  }
  return 2;
}

}  // namespace canbridge::bridge
