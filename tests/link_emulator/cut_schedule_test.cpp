#include "tools/link_emulator/cut_schedule.hpp"

#include <gtest/gtest.h>

#include <stdexcept>

namespace canbridge::emulator {
namespace {

using namespace std::chrono_literals;

RandomCuts ten_cuts(std::uint64_t seed) {
  RandomCuts options;
  options.seed = seed;
  options.count = 10;
  options.min_length = 2s;
  options.max_length = 2s;
  options.window_start = 5s;
  options.window_end = 65s;
  options.min_gap = 1s;
  return options;
}

bool same_cuts(const CutSchedule& x, const CutSchedule& y) {
  if (x.cuts().size() != y.cuts().size()) return false;
  for (std::size_t i = 0; i < x.cuts().size(); ++i) {
    if (x.cuts()[i].start != y.cuts()[i].start || x.cuts()[i].length != y.cuts()[i].length) {
      return false;
    }
  }
  return true;
}

TEST(CutSchedule, RandomCutsLieInsideTheWindowWithoutOverlapping) {
  for (std::uint64_t seed = 1; seed <= 50; ++seed) {
    const CutSchedule schedule = CutSchedule::random(ten_cuts(seed));
    ASSERT_EQ(schedule.cuts().size(), 10u);
    for (std::size_t i = 0; i < 10; ++i) {
      const Cut& cut = schedule.cuts()[i];
      EXPECT_EQ(cut.length, 2s);
      EXPECT_GE(cut.start, 5s);
      EXPECT_LE(cut.end(), 65s);
      if (i > 0) {
        EXPECT_GE(cut.start - schedule.cuts()[i - 1].end(), 1s) << "seed " << seed;
      }
    }
  }
}

TEST(CutSchedule, SameSeedSameCutsOtherSeedOtherCuts) {
  EXPECT_TRUE(same_cuts(CutSchedule::random(ten_cuts(9)), CutSchedule::random(ten_cuts(9))));
  EXPECT_FALSE(same_cuts(CutSchedule::random(ten_cuts(9)), CutSchedule::random(ten_cuts(10))));
}

TEST(CutSchedule, LengthsComeFromTheRange) {
  RandomCuts options = ten_cuts(4);
  options.min_length = 1s;
  options.max_length = 3s;
  const CutSchedule schedule = CutSchedule::random(options);
  bool varied = false;
  for (const Cut& cut : schedule.cuts()) {
    EXPECT_GE(cut.length, 1s);
    EXPECT_LE(cut.length, 3s);
    varied = varied || cut.length != schedule.cuts().front().length;
  }
  EXPECT_TRUE(varied);
}

TEST(CutSchedule, CutsThatCannotFitAreRejected) {
  RandomCuts options = ten_cuts(1);
  options.min_length = options.max_length = 6s;  // 60 s of cuts + 9 s of gaps > 60 s window
  EXPECT_THROW(CutSchedule::random(options), std::invalid_argument);
  options = ten_cuts(1);
  options.window_end = options.window_start;
  EXPECT_THROW(CutSchedule::random(options), std::invalid_argument);
}

TEST(CutSchedule, ExplicitCutsAreSortedAndMustNotOverlap) {
  const CutSchedule schedule = CutSchedule::from_list({{10s, 2s}, {3s, 1s}});
  ASSERT_EQ(schedule.cuts().size(), 2u);
  EXPECT_EQ(schedule.cuts()[0].start, 3s);
  EXPECT_EQ(schedule.cuts()[1].start, 10s);
  EXPECT_THROW(CutSchedule::from_list({{3s, 2s}, {4s, 1s}}), std::invalid_argument);
  EXPECT_THROW(CutSchedule::from_list({{3s, 0s}}), std::invalid_argument);
}

TEST(CutSchedule, InCutAndNextTransition) {
  const CutSchedule schedule = CutSchedule::from_list({{3s, 1s}, {10s, 2s}});
  EXPECT_FALSE(schedule.in_cut(0s));
  EXPECT_TRUE(schedule.in_cut(3s));
  EXPECT_TRUE(schedule.in_cut(4s - 1ns));
  EXPECT_FALSE(schedule.in_cut(4s));
  EXPECT_TRUE(schedule.in_cut(11s));
  EXPECT_EQ(schedule.next_transition(0s), 3s);
  EXPECT_EQ(schedule.next_transition(3s), 4s);
  EXPECT_EQ(schedule.next_transition(5s), 10s);
  EXPECT_EQ(schedule.next_transition(11s), 12s);
  EXPECT_EQ(schedule.next_transition(12s), std::nullopt);
  EXPECT_FALSE(CutSchedule().in_cut(1s));
}

}  // namespace
}  // namespace canbridge::emulator
