// Turns the surface's validated admission options into the limits its TCP listener enforces
// (backbone::AdmissionControl), so that backbone/ never sees config/.
#pragma once

#include <cstddef>

#include "backbone/admission_control.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// Links a configured gateway may hold at once when max_links is 0: its current link plus room for
// reconnects whose old link is not yet known dead.
constexpr std::size_t kLinksPerGateway = 4;
// And a few more, so a surface with few gateways still takes a reconnect storm.
constexpr std::size_t kSpareLinks = 8;

inline backbone::AdmissionLimits admission_limits(const config::SurfaceOptions& options) {
  backbone::AdmissionLimits limits;
  limits.max_pending_handshakes = options.admission.max_pending_handshakes;
  limits.handshake_timeout = options.admission.handshake_timeout;
  limits.max_links = options.admission.max_links != 0
                         ? options.admission.max_links
                         : kLinksPerGateway * options.gateways.size() + kSpareLinks;
  return limits;
}

}  // namespace canbridge::bridge
