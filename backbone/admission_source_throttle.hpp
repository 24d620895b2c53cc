// Per source address, how many handshakes a listener still lets a peer start, without sockets:
// every connection that ends before its handshake completed spends one of a refilling budget,
// handshakes in progress reserve one, so a source that keeps failing (a flood, a scanner, a
// misconfigured peer) is refused at accept, before it costs a TLS handshake or a pending slot,
// and cannot hold more than its budget of pending slots at once.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <unordered_map>

namespace canbridge::backbone {

struct SourceThrottleLimits {
  // Failures a source may have outstanding, pending connections included; 0: no throttling.
  std::size_t failure_budget = 0;
  // One failure is forgiven this long after it (the budget refills one per period).
  std::chrono::milliseconds refill_period{500};
  // Sources remembered at once; a new source beyond it, when none can be forgotten, is let in
  // untracked (the listener's global caps still hold), so the table's memory stays bounded.
  std::size_t max_sources = 1024;
};

struct SourceThrottleCounters {
  std::uint64_t refused = 0;    // connections refused at accept: their source's budget was spent
  std::uint64_t failures = 0;   // connections that ended without being admitted, charged
  std::uint64_t untracked = 0;  // let in untracked: the table was full
  std::uint64_t sources_peak = 0;
};

// Pure: sources are opaque keys (the caller's address bytes; empty: untracked), time injected.
// Not thread-safe.
class SourceThrottle {
 public:
  using Clock = std::chrono::steady_clock;
  using Source = std::string;

  explicit SourceThrottle(SourceThrottleLimits limits) : limits_(limits) {}

  // A connection from `source` wants to start: true if its budget, less its failures not yet
  // forgiven and its pending connections, has room; the connection then counts as pending for
  // the source until ended(). False: refuse it (counted).
  bool try_start(const Source& source, Clock::time_point now);
  enum class Outcome {
    admitted,  // its peer proved itself and was bound: clears the source's record
    proven,    // its peer completed the handshake but was not bound (e.g. a hello refused for
               // its claims): no failure, since only a holder of a configured key gets there
    failed,    // the handshake failed, timed out or was evicted, or the peer left: one failure
  };
  // A connection try_start let in no longer counts against its source's budget.
  void ended(const Source& source, Outcome outcome, Clock::time_point now);
  // A connection whose `proven` end was reported was bound after all: clears the record as an
  // `admitted` end would.
  void bound_after_proof(const Source& source);

  std::size_t sources() const noexcept { return sources_.size(); }
  const SourceThrottleCounters& counters() const noexcept { return counters_; }
  bool enabled() const noexcept { return limits_.failure_budget > 0; }

 private:
  struct Record {
    std::size_t pending = 0;
    // When every failure charged so far is forgiven: failures outstanding at `now` are
    // ceil((forgiven_at - now) / refill_period).
    Clock::time_point forgiven_at{};
  };
  std::size_t outstanding_failures(const Record& record, Clock::time_point now) const;
  // Forgets records with nothing pending and every failure forgiven.
  void forget_idle(Clock::time_point now);

  SourceThrottleLimits limits_;
  std::unordered_map<Source, Record> sources_;
  SourceThrottleCounters counters_;
};

}  // namespace canbridge::backbone
