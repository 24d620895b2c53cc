#include "tools/link_emulator/cut_schedule.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "tools/link_emulator/seeded_random.hpp"

namespace canbridge::emulator {

using std::chrono::nanoseconds;

CutSchedule CutSchedule::random(const RandomCuts& options) {
  if (options.count == 0) return CutSchedule();
  if (options.min_length <= nanoseconds::zero() || options.max_length < options.min_length) {
    throw std::invalid_argument("cut length must be positive (and min <= max)");
  }
  if (options.window_start < nanoseconds::zero() || options.window_end <= options.window_start ||
      options.min_gap < nanoseconds::zero()) {
    throw std::invalid_argument("cut window must be S0:S1 with 0 <= S0 < S1");
  }
  SeededRandom random(options.seed);
  std::vector<nanoseconds> lengths;
  nanoseconds occupied = options.min_gap * (options.count - 1);
  for (unsigned i = 0; i < options.count; ++i) {
    const auto spread =
        static_cast<std::uint64_t>((options.max_length - options.min_length).count());
    lengths.push_back(options.min_length +
                      nanoseconds(static_cast<nanoseconds::rep>(random.up_to(spread))));
    occupied += lengths.back();
  }
  const nanoseconds slack = (options.window_end - options.window_start) - occupied;
  if (slack < nanoseconds::zero()) {
    throw std::invalid_argument(std::to_string(options.count) +
                                " cuts (with their gaps) do not fit into the cut window");
  }
  // Sorted uniform offsets into the slack, each cut then shifted by everything before it: every
  // arrangement of the cuts inside the window is equally likely and none overlap.
  std::vector<nanoseconds> offsets;
  for (unsigned i = 0; i < options.count; ++i) {
    offsets.push_back(nanoseconds(
        static_cast<nanoseconds::rep>(random.up_to(static_cast<std::uint64_t>(slack.count())))));
  }
  std::sort(offsets.begin(), offsets.end());
  std::vector<Cut> cuts;
  nanoseconds before = options.window_start;
  for (unsigned i = 0; i < options.count; ++i) {
    cuts.push_back(Cut{before + offsets[i], lengths[i]});
    before += lengths[i] + options.min_gap;
  }
  return CutSchedule(std::move(cuts));
}

CutSchedule CutSchedule::from_list(std::vector<Cut> cuts) {
  std::sort(cuts.begin(), cuts.end(), [](const Cut& x, const Cut& y) { return x.start < y.start; });
  for (std::size_t i = 0; i < cuts.size(); ++i) {
    if (cuts[i].length <= nanoseconds::zero() || cuts[i].start < nanoseconds::zero()) {
      throw std::invalid_argument("a cut needs a start >= 0 and a positive length");
    }
    if (i > 0 && cuts[i].start < cuts[i - 1].end()) {
      throw std::invalid_argument("cuts overlap");
    }
  }
  return CutSchedule(std::move(cuts));
}

bool CutSchedule::in_cut(nanoseconds since_start) const {
  return std::any_of(cuts_.begin(), cuts_.end(), [&](const Cut& cut) {
    return cut.start <= since_start && since_start < cut.end();
  });
}

std::optional<nanoseconds> CutSchedule::next_transition(nanoseconds since_start) const {
  for (const Cut& cut : cuts_) {
    if (cut.start > since_start) return cut.start;
    if (cut.end() > since_start) return cut.end();
  }
  return std::nullopt;
}

}  // namespace canbridge::emulator
