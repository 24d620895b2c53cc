#include "backbone/admission_control.hpp"

#include <algorithm>

namespace canbridge::backbone {

AdmissionControl::AdmissionControl(AdmissionLimits limits)
    : limits_(limits), per_source_(limits.per_source) {
  limits_.max_pending_handshakes = std::max<std::size_t>(limits_.max_pending_handshakes, 1);
}

std::optional<AdmissionControl::ConnectionId> AdmissionControl::on_accepted(ConnectionId id,
                                                                            Clock::time_point now,
                                                                            bool talking) {
  return on_accepted_from({}, id, now, talking).evicted;
}

AdmissionControl::Accepted AdmissionControl::on_accepted_from(const Source& source, ConnectionId id,
                                                              Clock::time_point now, bool talking) {
  ++counters_.accepted;
  // A source refused here costs no pending slot and evicts nobody.
  if (!per_source_.try_start(source, now)) return {true, std::nullopt};
  std::optional<ConnectionId> evicted;
  if (pending_.size() >= limits_.max_pending_handshakes) {
    auto victim = std::find_if(pending_.begin(), pending_.end(),
                               [](const auto& p) { return !p.second.talking; });
    if (victim == pending_.end()) {
      victim = pending_.begin();
      ++counters_.evicted_talking;
    }
    evicted = victim->first;
    leave_pending(victim, false, now);
    ++counters_.evicted_pending;
  }
  const bool timed = limits_.handshake_timeout > std::chrono::milliseconds::zero();
  pending_.emplace(id, Pending{timed ? now + limits_.handshake_timeout : Clock::time_point::max(),
                               talking, false, source});
  counters_.pending_peak = std::max<std::uint64_t>(counters_.pending_peak, pending_.size());
  return {false, evicted};
}

void AdmissionControl::leave_pending(PendingMap::iterator it, bool admitted,
                                     Clock::time_point now) {
  using Outcome = SourceThrottle::Outcome;
  if (!it->second.upgraded) {
    per_source_.ended(it->second.source, admitted ? Outcome::admitted : Outcome::failed, now);
  } else if (admitted) {
    per_source_.bound_after_proof(it->second.source);
  }
  pending_.erase(it);
}

void AdmissionControl::on_talking(ConnectionId id) {
  if (auto it = pending_.find(id); it != pending_.end()) it->second.talking = true;
}

void AdmissionControl::on_upgraded(ConnectionId id, Clock::time_point now) {
  const auto it = pending_.find(id);
  if (it == pending_.end() || it->second.upgraded) return;
  it->second.upgraded = true;
  per_source_.ended(it->second.source, SourceThrottle::Outcome::proven, now);
}

AdmissionControl::Admission AdmissionControl::on_admitted(ConnectionId id) {
  if (admitted_.contains(id)) return Admission::admitted;
  const auto it = pending_.find(id);
  if (it == pending_.end()) return Admission::not_pending;
  // It proved itself (even if max_links refuses it now): its source is in good standing.
  leave_pending(it, true, Clock::time_point{});
  if (admitted_.size() >= limits_.max_links) {
    ++counters_.refused_link_cap;
    return Admission::refused;
  }
  admitted_.insert(id);
  ++counters_.admitted;
  return Admission::admitted;
}

void AdmissionControl::on_closed(ConnectionId id, Clock::time_point now) {
  if (const auto it = pending_.find(id); it != pending_.end()) leave_pending(it, false, now);
  admitted_.erase(id);
}

AdmissionCounters AdmissionControl::counters() const {
  AdmissionCounters counters = counters_;
  counters.per_source = per_source_.counters();
  return counters;
}

std::vector<AdmissionControl::ConnectionId> AdmissionControl::expired(Clock::time_point now) {
  std::vector<ConnectionId> due;
  // Deadlines grow with the id (see pending_), so the due ones are a prefix.
  while (!pending_.empty() && pending_.begin()->second.deadline <= now) {
    due.push_back(pending_.begin()->first);
    leave_pending(pending_.begin(), false, now);
    ++counters_.handshake_timeouts;
  }
  return due;
}

std::optional<AdmissionControl::Clock::time_point> AdmissionControl::next_deadline() const {
  if (pending_.empty()) return std::nullopt;
  return pending_.begin()->second.deadline;
}

}  // namespace canbridge::backbone
