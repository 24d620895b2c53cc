// When the emulated wire is cut: a seeded random or explicit list of non-overlapping outages,
// in time since the emulator started.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <vector>

namespace canbridge::emulator {

struct Cut {
  std::chrono::nanoseconds start{0};  // since the emulator started
  std::chrono::nanoseconds length{0};
  std::chrono::nanoseconds end() const { return start + length; }
};

struct RandomCuts {
  std::uint64_t seed = 1;
  unsigned count = 0;
  // Each cut's length is drawn uniformly from [min_length, max_length].
  std::chrono::nanoseconds min_length{0};
  std::chrono::nanoseconds max_length{0};
  // Every cut lies entirely inside [window_start, window_end].
  std::chrono::nanoseconds window_start{0};
  std::chrono::nanoseconds window_end{0};
  // At least this much connected time between two cuts (time to reconnect, for instance).
  std::chrono::nanoseconds min_gap{0};
};

class CutSchedule {
 public:
  CutSchedule() = default;  // never cut

  // Spreads the cuts uniformly over the window. Throws std::invalid_argument when they cannot
  // fit (startup only).
  static CutSchedule random(const RandomCuts& options);
  // Sorts the cuts by start. Throws std::invalid_argument on overlaps or non-positive lengths.
  static CutSchedule from_list(std::vector<Cut> cuts);

  const std::vector<Cut>& cuts() const { return cuts_; }
  bool empty() const { return cuts_.empty(); }
  bool in_cut(std::chrono::nanoseconds since_start) const;
  // The first start or end of a cut strictly after `since_start`; nullopt after the last cut.
  std::optional<std::chrono::nanoseconds> next_transition(
      std::chrono::nanoseconds since_start) const;

 private:
  explicit CutSchedule(std::vector<Cut> cuts) : cuts_(std::move(cuts)) {}
  std::vector<Cut> cuts_;
};

}  // namespace canbridge::emulator
