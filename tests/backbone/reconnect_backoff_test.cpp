// The reconnection wait of the backbone clients: doubling, capped, reset by a success, clamped.
#include "backbone/reconnect_backoff.hpp"

#include <gtest/gtest.h>

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;

TEST(ReconnectBackoff, DoublesUpToTheMaximumAndStartsOverAfterASuccess) {
  ReconnectBackoff backoff(100ms, 1000ms);
  EXPECT_EQ(backoff.next(), 100ms);
  EXPECT_EQ(backoff.next(), 200ms);
  EXPECT_EQ(backoff.next(), 400ms);
  EXPECT_EQ(backoff.next(), 800ms);
  EXPECT_EQ(backoff.next(), 1000ms);
  EXPECT_EQ(backoff.next(), 1000ms);
  backoff.reset();
  EXPECT_EQ(backoff.next(), 100ms);
}

TEST(ReconnectBackoff, PeekTellsTheNextWaitWithoutTakingIt) {
  ReconnectBackoff backoff(100ms, 400ms);
  EXPECT_EQ(backoff.peek(), 100ms);
  EXPECT_EQ(backoff.peek(), 100ms);
  EXPECT_EQ(backoff.next(), 100ms);
  EXPECT_EQ(backoff.peek(), 200ms);
  EXPECT_EQ(backoff.next(), 200ms);
  EXPECT_EQ(backoff.next(), 400ms);
  EXPECT_EQ(backoff.peek(), 400ms);
}

TEST(ReconnectBackoff, ImpossibleBoundsAreClampedSoItNeverSpins) {
  ReconnectBackoff zero(0ms, 0ms);
  EXPECT_EQ(zero.next(), 1ms);
  EXPECT_EQ(zero.next(), 1ms);
  ReconnectBackoff inverted(500ms, 100ms);
  EXPECT_EQ(inverted.max(), 500ms);
  EXPECT_EQ(inverted.next(), 500ms);
  EXPECT_EQ(inverted.next(), 500ms);
}

}  // namespace
}  // namespace canbridge::backbone
