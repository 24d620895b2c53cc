// The start-up warning of a role whose backbone is not authenticated (auth mode plain), so an
// unauthenticated bench never runs silently.
#pragma once

#include <optional>
#include <string>

#include "config/options.hpp"

namespace canbridge::bridge {

// The warning for this role's options; nothing when its backbone is authenticated.
std::optional<std::string> plain_warning(const config::GatewayOptions& options);
std::optional<std::string> plain_warning(const config::SurfaceOptions& options);

// Logs the warning (spdlog warn), once at start.
void warn_if_plain(const config::GatewayOptions& options);
void warn_if_plain(const config::SurfaceOptions& options);

}  // namespace canbridge::bridge
