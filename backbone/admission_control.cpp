#include "backbone/admission_control.hpp"

#include <algorithm>

namespace canbridge::backbone {

AdmissionControl::AdmissionControl(AdmissionLimits limits) : limits_(limits) {
  limits_.max_pending_handshakes = std::max<std::size_t>(limits_.max_pending_handshakes, 1);
}

std::optional<AdmissionControl::ConnectionId> AdmissionControl::on_accepted(ConnectionId id,
                                                                            Clock::time_point now,
                                                                            bool talking) {
  ++counters_.accepted;
  std::optional<ConnectionId> evicted;
  if (pending_.size() >= limits_.max_pending_handshakes) {
    auto victim = std::find_if(pending_.begin(), pending_.end(),
                               [](const auto& p) { return !p.second.talking; });
    if (victim == pending_.end()) {
      victim = pending_.begin();
      ++counters_.evicted_talking;
    }
    evicted = victim->first;
    pending_.erase(victim);
    ++counters_.evicted_pending;
  }
  const bool timed = limits_.handshake_timeout > std::chrono::milliseconds::zero();
  pending_.emplace(
      id, Pending{timed ? now + limits_.handshake_timeout : Clock::time_point::max(), talking});
  counters_.pending_peak = std::max<std::uint64_t>(counters_.pending_peak, pending_.size());
  return evicted;
}

void AdmissionControl::on_talking(ConnectionId id) {
  if (auto it = pending_.find(id); it != pending_.end()) it->second.talking = true;
}

AdmissionControl::Admission AdmissionControl::on_admitted(ConnectionId id) {
  if (admitted_.contains(id)) return Admission::admitted;
  if (pending_.erase(id) == 0) return Admission::not_pending;
  if (admitted_.size() >= limits_.max_links) {
    ++counters_.refused_link_cap;
    return Admission::refused;
  }
  admitted_.insert(id);
  ++counters_.admitted;
  return Admission::admitted;
}

void AdmissionControl::on_closed(ConnectionId id) {
  pending_.erase(id);
  admitted_.erase(id);
}

std::vector<AdmissionControl::ConnectionId> AdmissionControl::expired(Clock::time_point now) {
  std::vector<ConnectionId> due;
  // Deadlines grow with the id (see pending_), so the due ones are a prefix.
  while (!pending_.empty() && pending_.begin()->second.deadline <= now) {
    due.push_back(pending_.begin()->first);
    pending_.erase(pending_.begin());
    ++counters_.handshake_timeouts;
  }
  return due;
}

std::optional<AdmissionControl::Clock::time_point> AdmissionControl::next_deadline() const {
  if (pending_.empty()) return std::nullopt;
  return pending_.begin()->second.deadline;
}

}  // namespace canbridge::backbone
