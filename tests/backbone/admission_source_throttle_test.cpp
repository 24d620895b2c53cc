#include "backbone/admission_source_throttle.hpp"

#include <gtest/gtest.h>

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;
const SourceThrottle::Clock::time_point kThrottleStart{};
using Outcome = SourceThrottle::Outcome;

SourceThrottle make_throttle(std::size_t budget, std::size_t max_sources = 1024) {
  return SourceThrottle({budget, 500ms, max_sources});
}

TEST(SourceThrottle, OneSourceHoldsAtMostItsBudgetOfPendingConnections) {
  auto throttle = make_throttle(3);
  EXPECT_TRUE(throttle.try_start("flood", kThrottleStart));
  EXPECT_TRUE(throttle.try_start("flood", kThrottleStart));
  EXPECT_TRUE(throttle.try_start("flood", kThrottleStart));
  EXPECT_FALSE(throttle.try_start("flood", kThrottleStart));
  // Another source is not affected by the first one's load.
  EXPECT_TRUE(throttle.try_start("gateway", kThrottleStart));
  EXPECT_EQ(throttle.counters().refused, 1u);
}

TEST(SourceThrottle, FailuresSpendTheBudgetAndAreForgivenOnePerRefillPeriod) {
  auto throttle = make_throttle(2);
  ASSERT_TRUE(throttle.try_start("flood", kThrottleStart));
  ASSERT_TRUE(throttle.try_start("flood", kThrottleStart));
  throttle.ended("flood", Outcome::failed, kThrottleStart);
  throttle.ended("flood", Outcome::failed, kThrottleStart);
  EXPECT_EQ(throttle.counters().failures, 2u);
  // Two failures outstanding: nothing until one is forgiven (500 ms after the first).
  EXPECT_FALSE(throttle.try_start("flood", kThrottleStart + 499ms));
  EXPECT_TRUE(throttle.try_start("flood", kThrottleStart + 500ms));
  EXPECT_FALSE(throttle.try_start("flood", kThrottleStart + 600ms));
  throttle.ended(
      "flood", Outcome::failed,
      kThrottleStart + 600ms);  // failures now outstanding until kThrottleStart + 1500 ms
  EXPECT_FALSE(throttle.try_start("flood", kThrottleStart + 999ms));
  EXPECT_TRUE(throttle.try_start("flood", kThrottleStart + 1000ms));
  EXPECT_EQ(throttle.counters().refused, 3u);
}

TEST(SourceThrottle, AnAdmittedConnectionClearsItsSourcesFailures) {
  auto throttle = make_throttle(2);
  ASSERT_TRUE(throttle.try_start("gateway", kThrottleStart));
  ASSERT_TRUE(throttle.try_start("gateway", kThrottleStart));
  throttle.ended("gateway", Outcome::failed, kThrottleStart);    // e.g. evicted
  throttle.ended("gateway", Outcome::admitted, kThrottleStart);  // the retry proved itself
  EXPECT_EQ(throttle.sources(), 0u);                             // nothing left behind
  EXPECT_TRUE(throttle.try_start("gateway", kThrottleStart));
  EXPECT_TRUE(throttle.try_start("gateway", kThrottleStart));
}

TEST(SourceThrottle, AProvenPeerLeftUnboundIsNoFailure) {
  auto throttle = make_throttle(1);
  for (int i = 0; i < 10; ++i) {
    ASSERT_TRUE(throttle.try_start("rogue", kThrottleStart));
    throttle.ended("rogue", Outcome::proven, kThrottleStart);
  }
  EXPECT_EQ(throttle.counters().failures, 0u);
  EXPECT_EQ(throttle.sources(), 0u);
}

TEST(SourceThrottle, RecordsAreForgottenOnceIdleAndTheTableIsBounded) {
  auto throttle = make_throttle(1, 2);
  ASSERT_TRUE(throttle.try_start("a", kThrottleStart));
  ASSERT_TRUE(throttle.try_start("b", kThrottleStart));
  // Full, nothing idle: a third source is let in untracked rather than refused.
  EXPECT_TRUE(throttle.try_start("c", kThrottleStart));
  EXPECT_TRUE(throttle.try_start("c", kThrottleStart));
  EXPECT_EQ(throttle.counters().untracked, 2u);
  EXPECT_EQ(throttle.sources(), 2u);
  throttle.ended("a", Outcome::failed, kThrottleStart);
  throttle.ended("c", Outcome::failed, kThrottleStart);  // untracked: no effect
  // "a"'s failure is forgiven at kThrottleStart + 500 ms: then its record can make room for "c".
  EXPECT_TRUE(throttle.try_start("c", kThrottleStart + 500ms));
  EXPECT_FALSE(throttle.try_start("c", kThrottleStart + 500ms));
  EXPECT_EQ(throttle.sources(), 2u);
  EXPECT_EQ(throttle.counters().sources_peak, 2u);
}

TEST(SourceThrottle, NoBudgetOrNoSourceMeansNoThrottling) {
  auto off = make_throttle(0);
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(off.try_start("flood", kThrottleStart));
  EXPECT_EQ(off.sources(), 0u);
  auto on = make_throttle(1);
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(on.try_start("", kThrottleStart));
}

}  // namespace
}  // namespace canbridge::backbone
