// Turns the surface's validated admission options into the limits its TCP listener enforces
// (backbone::AdmissionControl), so that backbone/ never sees config/.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstddef>

#include "backbone/admission_control.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// Links a configured gateway may hold at once when max_links is 0: its current link plus room for
// reconnects whose old link is not yet known dead.
constexpr std::size_t kLinksPerGateway = 4;
// And a few more, so a surface with few gateways still takes a reconnect storm.
constexpr std::size_t kSpareLinks = 8;
// One source address may hold at most this share of the pending handshakes (failures not yet
// forgiven included), so one flooding host can never fill them and evict a configured gateway's
// handshake; at the default 32 pending, 8.
constexpr std::size_t kPendingShareOfOneSource = 4;
// A source's failure is forgiven after this: a host that keeps failing gets about two
// handshakes a second, and a fixed key gets through within a few seconds.
constexpr std::chrono::milliseconds kSourceFailureForgiven{500};

inline backbone::AdmissionLimits admission_limits(const config::SurfaceOptions& options) {
  backbone::AdmissionLimits limits;
  limits.max_pending_handshakes = options.admission.max_pending_handshakes;
  limits.handshake_timeout = options.admission.handshake_timeout;
  limits.max_links = options.admission.max_links != 0
                         ? options.admission.max_links
                         : kLinksPerGateway * options.gateways.size() + kSpareLinks;
  limits.per_source.failure_budget =
      std::max<std::size_t>(1, limits.max_pending_handshakes / kPendingShareOfOneSource);
  limits.per_source.refill_period = kSourceFailureForgiven;
  return limits;
}

}  // namespace canbridge::bridge
