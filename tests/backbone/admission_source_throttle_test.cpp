#include "backbone/admission_source_throttle.hpp"

#include <gtest/gtest.h>

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;
const SourceThrottle::Clock::time_point t0{};
using Outcome = SourceThrottle::Outcome;

SourceThrottle make(std::size_t budget, std::size_t max_sources = 1024) {
  return SourceThrottle({budget, 500ms, max_sources});
}

TEST(SourceThrottle, OneSourceHoldsAtMostItsBudgetOfPendingConnections) {
  auto throttle = make(3);
  EXPECT_TRUE(throttle.try_start("flood", t0));
  EXPECT_TRUE(throttle.try_start("flood", t0));
  EXPECT_TRUE(throttle.try_start("flood", t0));
  EXPECT_FALSE(throttle.try_start("flood", t0));
  // Another source is not affected by the first one's load.
  EXPECT_TRUE(throttle.try_start("gateway", t0));
  EXPECT_EQ(throttle.counters().refused, 1u);
}

TEST(SourceThrottle, FailuresSpendTheBudgetAndAreForgivenOnePerRefillPeriod) {
  auto throttle = make(2);
  ASSERT_TRUE(throttle.try_start("flood", t0));
  ASSERT_TRUE(throttle.try_start("flood", t0));
  throttle.ended("flood", Outcome::failed, t0);
  throttle.ended("flood", Outcome::failed, t0);
  EXPECT_EQ(throttle.counters().failures, 2u);
  // Two failures outstanding: nothing until one is forgiven (500 ms after the first).
  EXPECT_FALSE(throttle.try_start("flood", t0 + 499ms));
  EXPECT_TRUE(throttle.try_start("flood", t0 + 500ms));
  EXPECT_FALSE(throttle.try_start("flood", t0 + 600ms));
  throttle.ended("flood", Outcome::failed,
                 t0 + 600ms);  // failures now outstanding until t0 + 1500 ms
  EXPECT_FALSE(throttle.try_start("flood", t0 + 999ms));
  EXPECT_TRUE(throttle.try_start("flood", t0 + 1000ms));
  EXPECT_EQ(throttle.counters().refused, 3u);
}

TEST(SourceThrottle, AnAdmittedConnectionClearsItsSourcesFailures) {
  auto throttle = make(2);
  ASSERT_TRUE(throttle.try_start("gateway", t0));
  ASSERT_TRUE(throttle.try_start("gateway", t0));
  throttle.ended("gateway", Outcome::failed, t0);    // e.g. evicted
  throttle.ended("gateway", Outcome::admitted, t0);  // the retry proved itself
  EXPECT_EQ(throttle.sources(), 0u);                 // nothing left behind
  EXPECT_TRUE(throttle.try_start("gateway", t0));
  EXPECT_TRUE(throttle.try_start("gateway", t0));
}

TEST(SourceThrottle, AProvenPeerLeftUnboundIsNoFailure) {
  auto throttle = make(1);
  for (int i = 0; i < 10; ++i) {
    ASSERT_TRUE(throttle.try_start("rogue", t0));
    throttle.ended("rogue", Outcome::proven, t0);
  }
  EXPECT_EQ(throttle.counters().failures, 0u);
  EXPECT_EQ(throttle.sources(), 0u);
}

TEST(SourceThrottle, RecordsAreForgottenOnceIdleAndTheTableIsBounded) {
  auto throttle = make(1, 2);
  ASSERT_TRUE(throttle.try_start("a", t0));
  ASSERT_TRUE(throttle.try_start("b", t0));
  // Full, nothing idle: a third source is let in untracked rather than refused.
  EXPECT_TRUE(throttle.try_start("c", t0));
  EXPECT_TRUE(throttle.try_start("c", t0));
  EXPECT_EQ(throttle.counters().untracked, 2u);
  EXPECT_EQ(throttle.sources(), 2u);
  throttle.ended("a", Outcome::failed, t0);
  throttle.ended("c", Outcome::failed, t0);  // untracked: no effect
  // "a"'s failure is forgiven at t0 + 500 ms: then its record can make room for "c".
  EXPECT_TRUE(throttle.try_start("c", t0 + 500ms));
  EXPECT_FALSE(throttle.try_start("c", t0 + 500ms));
  EXPECT_EQ(throttle.sources(), 2u);
  EXPECT_EQ(throttle.counters().sources_peak, 2u);
}

TEST(SourceThrottle, NoBudgetOrNoSourceMeansNoThrottling) {
  auto off = make(0);
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(off.try_start("flood", t0));
  EXPECT_EQ(off.sources(), 0u);
  auto on = make(1);
  for (int i = 0; i < 100; ++i) EXPECT_TRUE(on.try_start("", t0));
}

}  // namespace
}  // namespace canbridge::backbone
