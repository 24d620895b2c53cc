// LineLossCounter: process frames lost on the line, from the sender's running count per batch.
#include "bridge/line_loss_counter.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

TEST(LineLossCounter, CountsTheFramesOfBatchesThatNeverArrived) {
  LineLossCounter c;
  c.on_batch(7, 10, 10);  // the first batch: the baseline, nothing lost before it is ours
  EXPECT_EQ(c.lost(), 0u);
  c.on_batch(7, 15, 5);  // the next one
  EXPECT_EQ(c.lost(), 0u);
  c.on_batch(7, 40, 5);  // 20 frames in batches that were lost between
  EXPECT_EQ(c.lost(), 20u);
  c.on_batch(7, 41, 1);
  EXPECT_EQ(c.lost(), 20u);
}

TEST(LineLossCounter, ANewPeerProcessStartsAFreshCount) {
  LineLossCounter c;
  c.on_batch(7, 100, 10);
  // The peer restarted: its count starts again, and even a count above the old one is a
  // baseline, not a loss.
  c.on_batch(8, 500, 10);
  EXPECT_EQ(c.lost(), 0u);
  c.on_batch(8, 530, 10);
  EXPECT_EQ(c.lost(), 20u);
}

TEST(LineLossCounter, BatchesWithoutACountAreIgnored) {
  LineLossCounter c;
  c.on_batch(7, 10, 10);
  c.on_batch(7, 0, 3);  // a reliable batch
  c.on_batch(7, 12, 2);
  EXPECT_EQ(c.lost(), 0u);
}

}  // namespace
}  // namespace canbridge::bridge
