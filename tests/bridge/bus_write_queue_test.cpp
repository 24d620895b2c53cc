// The FIFO of frames waiting for bus room (issue 14, "exactly once to the bus"): nothing
// overtakes a waiting frame, reliable frames are never dropped, process data is beyond a bound,
// units go whole, and the backlog flag has hysteresis.
#include "bridge/bus_write_queue.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <vector>

namespace canbridge::bridge {
namespace {

using QueueLane = BusWriteQueue::Lane;
using Drop = BusWriteQueue::Drop;

can::Frame sdo(std::uint32_t seq) {
  return can::Frame::standard(
      0x602, {0x40, 0x00, 0x20, static_cast<std::uint8_t>(seq), static_cast<std::uint8_t>(seq >> 8),
              static_cast<std::uint8_t>(seq >> 16)});
}
can::Frame pdo(std::uint32_t seq) {
  return can::Frame::standard(0x182, {static_cast<std::uint8_t>(seq)});
}

std::uint64_t dropped(const BusWriteQueue& q, Drop reason) {
  return q.counters().dropped[static_cast<std::size_t>(reason)];
}

TEST(BusWriteQueue, WritesAtOnceWhileNothingWaitsAndTheBusHasRoom) {
  BusWriteQueue q({});
  std::vector<can::Frame> now;
  EXPECT_TRUE(q.offer(std::vector{sdo(1)}, QueueLane::reliable, 1, now));
  ASSERT_EQ(now.size(), 1u);
  EXPECT_EQ(now[0], sdo(1));
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.counters().frames_written, 1u);
  EXPECT_EQ(q.counters().frames_waited, 0u);
}

TEST(BusWriteQueue, OnceAFrameWaitsEveryLaterFrameWaitsBehindIt) {
  BusWriteQueue q({});
  std::vector<can::Frame> now;
  EXPECT_TRUE(q.offer(std::vector{sdo(1)}, QueueLane::reliable, 0, now));  // no room: waits
  // The bus has room again, but sdo(1) has not been written yet: sdo(2) must not pass it.
  EXPECT_TRUE(q.offer(std::vector{sdo(2)}, QueueLane::reliable, 10, now));
  EXPECT_TRUE(q.offer(std::vector{pdo(3)}, QueueLane::process_data, 10, now));
  EXPECT_TRUE(now.empty());
  EXPECT_EQ(q.waiting(), 3u);
  EXPECT_EQ(q.head_frames(), 1u);
  std::vector<can::Frame> out;
  q.take(2, out);
  EXPECT_EQ(out, (std::vector{sdo(1), sdo(2)}));
  q.take(5, out);
  EXPECT_EQ(out, (std::vector{sdo(1), sdo(2), pdo(3)}));
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(q.head_frames(), 0u);
  EXPECT_EQ(q.counters().frames_waited, 3u);
  EXPECT_EQ(q.counters().peak_waiting, 3u);
}

TEST(BusWriteQueue, AUnitGoesWholeAndNothingBehindItOvertakesIt) {
  BusWriteQueue q({});
  std::vector<can::Frame> now;
  const std::vector packet{pdo(1), pdo(2), pdo(3)};
  EXPECT_TRUE(q.offer(packet, QueueLane::reliable, 2, now));  // 2 free slots: not enough, waits
  EXPECT_TRUE(now.empty());
  EXPECT_TRUE(q.offer(std::vector{sdo(4)}, QueueLane::reliable, 2, now));
  EXPECT_EQ(q.head_frames(), 3u);
  std::vector<can::Frame> out;
  q.take(2, out);  // sdo(4) would fit, but the packet ahead of it does not
  EXPECT_TRUE(out.empty());
  q.take(3, out);
  EXPECT_EQ(out, packet);
  q.take(1, out);
  EXPECT_EQ(out.back(), sdo(4));
}

TEST(BusWriteQueue, ReliableFramesAreNeverDroppedProcessDataIsBeyondTheBound) {
  BusWriteQueue::Options options;
  options.max_waiting_for_process_data = 3;
  BusWriteQueue q(options);
  std::vector<can::Frame> now;
  for (std::uint32_t i = 0; i < 3; ++i)
    EXPECT_TRUE(q.offer(std::vector{sdo(i)}, QueueLane::reliable, 0, now));
  EXPECT_FALSE(q.offer(std::vector{pdo(9)}, QueueLane::process_data, 0, now));
  for (std::uint32_t i = 3; i < 100; ++i) {
    EXPECT_TRUE(q.offer(std::vector{sdo(i)}, QueueLane::reliable, 0, now));
  }
  EXPECT_EQ(q.waiting(), 100u);
  EXPECT_EQ(dropped(q, Drop::process_data_backlog), 1u);
  EXPECT_EQ(q.dropped(), 1u);
  std::vector<can::Frame> out;
  q.take(1000, out);
  ASSERT_EQ(out.size(), 100u);
  for (std::uint32_t i = 0; i < 100; ++i) EXPECT_EQ(out[i], sdo(i)) << i;
}

TEST(BusWriteQueue, AUnitTheBusCanNeverHoldIsDroppedNotWaitedForever) {
  BusWriteQueue::Options options;
  options.bus_capacity = 2;
  BusWriteQueue q(options);
  std::vector<can::Frame> now;
  EXPECT_FALSE(q.offer(std::vector{pdo(1), pdo(2), pdo(3)}, QueueLane::reliable, 2, now));
  EXPECT_TRUE(now.empty());
  EXPECT_TRUE(q.empty());
  EXPECT_EQ(dropped(q, Drop::larger_than_bus), 3u);
  EXPECT_TRUE(q.offer(std::vector{pdo(1), pdo(2)}, QueueLane::reliable, 2, now));
  EXPECT_EQ(now.size(), 2u);
}

TEST(BusWriteQueue, BacklogTurnsOnAboveTheHighWatermarkAndOffAtTheLow) {
  BusWriteQueue::Options options;
  options.high_watermark = 4;
  options.low_watermark = 2;
  BusWriteQueue q(options);
  std::vector<can::Frame> now, out;
  for (std::uint32_t i = 0; i < 4; ++i) q.offer(std::vector{sdo(i)}, QueueLane::reliable, 0, now);
  EXPECT_FALSE(q.backlogged());  // at the high watermark, not above
  q.offer(std::vector{sdo(4)}, QueueLane::reliable, 0, now);
  EXPECT_TRUE(q.backlogged());
  q.take(2, out);  // 3 waiting: still above the low watermark
  EXPECT_TRUE(q.backlogged());
  q.take(1, out);
  EXPECT_FALSE(q.backlogged());
  EXPECT_EQ(q.counters().backlogs, 1u);
}

TEST(BusWriteQueue, ClosingDropsWhatWaitsAndCountsIt) {
  BusWriteQueue::Options options;
  options.high_watermark = 1;
  options.low_watermark = 0;
  BusWriteQueue q(options);
  std::vector<can::Frame> now;
  q.offer(std::vector{sdo(1), sdo(2)}, QueueLane::reliable, 0, now);
  EXPECT_TRUE(q.backlogged());
  q.clear();
  EXPECT_TRUE(q.empty());
  EXPECT_FALSE(q.backlogged());
  EXPECT_EQ(dropped(q, Drop::closed), 2u);
}

// Property: whatever the bus's room does, the frames written (at once or after waiting) are
// exactly the accepted ones, in the order offered, units unbroken; only process data is dropped.
TEST(BusWriteQueue, NeverReordersUnderRandomRoom) {
  std::mt19937 random(14);
  for (int round = 0; round < 200; ++round) {
    BusWriteQueue::Options options;
    options.bus_capacity = 8;
    options.max_waiting_for_process_data = 1 + random() % 20;
    BusWriteQueue q(options);
    std::vector<can::Frame> accepted, written, batch;
    std::uint32_t seq = 0;
    std::uint64_t reliable_offered = 0, reliable_written = 0;
    for (int step = 0; step < 300; ++step) {
      const std::size_t room = random() % 6;
      if (random() % 3 != 0) {
        const bool reliable = random() % 2 == 0;
        std::vector<can::Frame> unit;
        const std::size_t n = 1 + random() % 4;
        for (std::size_t i = 0; i < n; ++i) unit.push_back(reliable ? sdo(seq++) : pdo(seq++));
        batch.clear();
        if (q.offer(unit, reliable ? QueueLane::reliable : QueueLane::process_data, room, batch)) {
          accepted.insert(accepted.end(), unit.begin(), unit.end());
          if (reliable) reliable_offered += n;
        } else {
          ASSERT_FALSE(reliable) << "a reliable unit was dropped";
        }
        // Written at once only if it fits the room it was offered with, all of it.
        ASSERT_TRUE(batch.empty() || (batch.size() == n && n <= room));
      } else {
        batch.clear();
        q.take(room, batch);
        ASSERT_LE(batch.size(), room);
      }
      written.insert(written.end(), batch.begin(), batch.end());
    }
    batch.clear();
    q.take(std::numeric_limits<std::size_t>::max(), batch);
    written.insert(written.end(), batch.begin(), batch.end());
    ASSERT_EQ(written, accepted) << "round " << round;
    for (const can::Frame& f : written) reliable_written += f.id == 0x602;
    EXPECT_EQ(reliable_written, reliable_offered);
    EXPECT_EQ(q.counters().frames_written, written.size());
  }
}

}  // namespace
}  // namespace canbridge::bridge
