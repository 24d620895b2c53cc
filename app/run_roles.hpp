// Runs the gateway and surface roles as processes: opens their SocketCAN buses and backbone
// sockets from validated options, logs periodic counters, and shuts down in order on a signal.
#pragma once

#include "app/reload_on_hangup.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// Both return the process exit status: 0 after a signal, 1 when the role stopped itself because
// one of its loops failed. Startup errors are thrown (std::exception) to main. `reload`: the file
// SIGHUP re-reads (reload_on_hangup.hpp).
int run_gateway(const config::GatewayOptions& options, const HangupReloadSource& reload = {});
int run_surface(const config::SurfaceOptions& options, const HangupReloadSource& reload = {});

}  // namespace canbridge::bridge
