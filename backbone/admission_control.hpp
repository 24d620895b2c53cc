// Who a TCP listener lets in and for how long, without sockets: pending handshakes are capped
// (a new one beyond the cap evicts the oldest) and timed out, admitted links are capped, and a
// source that keeps failing is refused at accept, so a flood of idle or failing connections
// cannot hold the surface's port, lock a configured peer out or grow its memory.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "backbone/admission_source_throttle.hpp"

namespace canbridge::backbone {

struct AdmissionLimits {
  // Connections accepted and not yet admitted (TLS and session hello in progress); at least 1.
  std::size_t max_pending_handshakes = 32;
  // A pending connection is closed this long after it was accepted; zero: never.
  std::chrono::milliseconds handshake_timeout{2000};
  // Admitted links at once (a bound session each); a link admitted beyond it is refused.
  std::size_t max_links = 12;
  // Per source address (SourceThrottle); off unless the owner sets a failure budget.
  SourceThrottleLimits per_source{};

  // No caps and no deadline: for a listener whose owner never calls admitted (tests, benches).
  static AdmissionLimits unlimited() {
    constexpr auto kNoCap = std::numeric_limits<std::size_t>::max();
    return {kNoCap, std::chrono::milliseconds::zero(), kNoCap, {}};
  }
};

struct AdmissionCounters {
  std::uint64_t accepted = 0;
  std::uint64_t evicted_pending = 0;     // a pending one closed to make room for a new one
  std::uint64_t evicted_talking = 0;     // ... of which had sent something (all were talking)
  std::uint64_t handshake_timeouts = 0;  // pending past handshake_timeout
  std::uint64_t refused_link_cap = 0;    // admitted beyond max_links: closed instead
  std::uint64_t admitted = 0;
  std::uint64_t pending_peak = 0;
  SourceThrottleCounters per_source;
};

// Pure: connection ids in (the caller numbers its connections in accept order), decisions out,
// time injected. Not thread-safe.
class AdmissionControl {
 public:
  using ConnectionId = std::uint64_t;
  using Clock = std::chrono::steady_clock;
  using Source = SourceThrottle::Source;

  explicit AdmissionControl(AdmissionLimits limits);

  // A new connection, pending from now on; `talking`: its peer has sent something already.
  // Returns the pending connection the caller must close to make room (it is no longer tracked),
  // if the cap was reached: the oldest silent one, else the oldest. A real peer speaks at once
  // (TLS ClientHello, session hello), so connections that only hold a slot go first.
  std::optional<ConnectionId> on_accepted(ConnectionId id, Clock::time_point now,
                                          bool talking = false);
  struct Accepted {
    bool refused = false;                 // its source's failure budget is spent: close it
    std::optional<ConnectionId> evicted;  // as on_accepted's result
  };
  // on_accepted for a connection from `source` (address bytes; empty: not throttled): refused
  // at once, untracked, if the source has failed too often lately (SourceThrottle); every
  // pending connection that ends without being admitted is one failure of its source.
  Accepted on_accepted_from(const Source& source, ConnectionId id, Clock::time_point now,
                            bool talking = false);
  // The pending connection's peer has sent something.
  void on_talking(ConnectionId id);
  // The pending connection's handshake (TLS) completed: its peer holds a configured key, so it
  // no longer counts against its source's budget, and if it ends unbound (a hello refused for
  // its claims) that is no failure of its source. It stays pending until admitted or closed.
  void on_upgraded(ConnectionId id, Clock::time_point now);

  enum class Admission {
    admitted,     // counted against max_links until on_closed
    refused,      // max_links reached: close it (no longer tracked)
    not_pending,  // evicted, timed out or closed already: close it
  };
  // The connection completed its handshake (its session is bound). Again for an admitted one:
  // admitted, nothing changes.
  Admission on_admitted(ConnectionId id);

  // The connection ended (either state); unknown ids are ignored. One still pending is a
  // failure of its source, charged at `now`.
  void on_closed(ConnectionId id, Clock::time_point now);

  // The pending connections whose deadline is at or before `now`, oldest first: the caller closes
  // them (they are no longer tracked).
  std::vector<ConnectionId> expired(Clock::time_point now);
  // The earliest pending deadline; nullopt when nothing is pending.
  std::optional<Clock::time_point> next_deadline() const;

  bool is_pending(ConnectionId id) const { return pending_.contains(id); }
  std::size_t pending() const noexcept { return pending_.size(); }
  std::size_t admitted() const noexcept { return admitted_.size(); }
  AdmissionCounters counters() const;
  const AdmissionLimits& limits() const noexcept { return limits_; }

 private:
  AdmissionLimits limits_;
  struct Pending {
    Clock::time_point deadline;
    bool talking = false;
    bool upgraded = false;
    Source source;
  };
  using PendingMap = std::map<ConnectionId, Pending>;
  // Takes a connection out of pending; charges its source a failure unless `admitted` or its
  // handshake had completed (on_upgraded settled its source's account then).
  void leave_pending(PendingMap::iterator it, bool admitted, Clock::time_point now);
  // Pending, by id: ids grow in accept order, so begin() is the oldest (and earliest deadline:
  // every deadline is its accept time plus the same timeout).
  PendingMap pending_;
  std::set<ConnectionId> admitted_;
  AdmissionCounters counters_;
  SourceThrottle per_source_;
};

}  // namespace canbridge::backbone
