#include "backbone/admission_source_throttle.hpp"

#include <algorithm>

namespace canbridge::backbone {

std::size_t SourceThrottle::outstanding_failures(const Record& record,
                                                 Clock::time_point now) const {
  if (record.forgiven_at <= now) return 0;
  const auto period = std::max<Clock::duration>(limits_.refill_period, Clock::duration{1});
  const auto debt = record.forgiven_at - now;
  return static_cast<std::size_t>((debt + period - Clock::duration{1}) / period);
}

void SourceThrottle::forget_idle(Clock::time_point now) {
  std::erase_if(sources_, [now](const auto& entry) {
    return entry.second.pending == 0 && entry.second.forgiven_at <= now;
  });
}

bool SourceThrottle::try_start(const Source& source, Clock::time_point now) {
  if (!enabled() || source.empty()) return true;
  auto it = sources_.find(source);
  if (it == sources_.end()) {
    // Only a full table is swept: one sweep frees every idle record at once.
    if (sources_.size() >= limits_.max_sources) forget_idle(now);
    if (sources_.size() >= limits_.max_sources) {
      ++counters_.untracked;
      return true;
    }
    it = sources_.emplace(source, Record{}).first;
    counters_.sources_peak = std::max<std::uint64_t>(counters_.sources_peak, sources_.size());
  }
  Record& record = it->second;
  if (record.pending + outstanding_failures(record, now) >= limits_.failure_budget) {
    ++counters_.refused;
    return false;
  }
  ++record.pending;
  return true;
}

void SourceThrottle::ended(const Source& source, Outcome outcome, Clock::time_point now) {
  if (!enabled() || source.empty()) return;
  const auto it = sources_.find(source);
  if (it == sources_.end()) return;  // let in untracked
  Record& record = it->second;
  if (record.pending > 0) --record.pending;
  if (outcome == Outcome::admitted) {
    // A peer that proved itself from here: its earlier failures were its own retries, or
    // someone else's behind the same address; either way the source is in good standing.
    record.forgiven_at = Clock::time_point{};
  } else if (outcome == Outcome::failed) {
    ++counters_.failures;
    record.forgiven_at = std::max(record.forgiven_at, now) + limits_.refill_period;
  }
  if (record.pending == 0 && record.forgiven_at <= now) sources_.erase(it);
}

void SourceThrottle::bound_after_proof(const Source& source) {
  if (!enabled() || source.empty()) return;
  const auto it = sources_.find(source);
  if (it == sources_.end()) return;
  it->second.forgiven_at = Clock::time_point{};
  if (it->second.pending == 0) sources_.erase(it);
}

}  // namespace canbridge::backbone
