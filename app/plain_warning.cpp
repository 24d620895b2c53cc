#include "app/plain_warning.hpp"

#include <spdlog/spdlog.h>

namespace canbridge::bridge {

namespace {

constexpr const char* kWhy =
    "; for a bench on loopback or a serial line only: set backbone.auth.mode to psk or "
    "certificates anywhere else (docs/security.md)";

}  // namespace

std::optional<std::string> plain_warning(const config::GatewayOptions& options) {
  if (options.auth.mode != config::AuthMode::plain) return std::nullopt;
  const std::string link = options.serial ? "serial line " + options.serial->device
                                          : "tcp " + options.connect.to_string();
  return "gateway " + options.name + ": backbone is NOT authenticated (auth mode plain, " + link +
         "): this gateway cannot tell its surface from any other peer" + kWhy;
}

std::optional<std::string> plain_warning(const config::SurfaceOptions& options) {
  if (options.auth.mode != config::AuthMode::plain) return std::nullopt;
  std::string links;
  if (!options.listen.host.empty()) links = "listening on " + options.listen.to_string();
  for (const auto& line : options.serial) {
    links += (links.empty() ? "serial line " : ", serial line ") + line.device;
  }
  return "surface " + options.name + ": backbone is NOT authenticated (auth mode plain, " + links +
         "): any peer that reaches it may put frames on bus " + options.bus + kWhy;
}

void warn_if_plain(const config::GatewayOptions& options) {
  if (auto warning = plain_warning(options)) spdlog::warn("{}", *warning);
}

void warn_if_plain(const config::SurfaceOptions& options) {
  if (auto warning = plain_warning(options)) spdlog::warn("{}", *warning);
}

}  // namespace canbridge::bridge
