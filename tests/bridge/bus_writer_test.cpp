// The shell around BusWriteQueue on a virtual bus whose medium the test holds: frames wait while
// the bus's transmit queue is full and go, in order, as room appears, without any polling.
#include "bridge/bus_writer.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "can/virtual_bus.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using QueueLane = BusWriteQueue::Lane;

can::Frame emcy(std::uint8_t seq) {
  return can::Frame::standard(0x085, {0x00, 0x10, 0x01, seq});
}

class BusWriterTest : public ::testing::Test {
 protected:
  BusWriterTest() { writer.start(); }
  ~BusWriterTest() override {
    writer.stop();
    bus->close();
    far.close();
    EXPECT_TRUE(test::run_until(io, [&] { return far.done(); }));
  }

  boost::asio::io_context io{1};
  can::VirtualBus medium{io.get_executor(), "held"};
  std::unique_ptr<can::Bus> bus = medium.connect("writer", 3);  // a 3-frame transmit queue
  test::BusRecorder far{io, medium.connect("far")};
  std::vector<can::Frame> written;
  std::vector<bool> backlog_changes;
  BusWriter writer{io.get_executor(), *bus,
                   [] {
                     BusWriteQueue::Options o;
                     o.high_watermark = 4;
                     o.low_watermark = 1;
                     return o;
                   }(),
                   [this](std::span<const can::Frame> frames) {
                     written.insert(written.end(), frames.begin(), frames.end());
                   },
                   [this](bool backlogged) { backlog_changes.push_back(backlogged); }};
};

TEST_F(BusWriterTest, FramesWaitForRoomAndGoInOrderAsItAppears) {
  medium.hold(true);
  for (std::uint8_t i = 0; i < 10; ++i) ASSERT_TRUE(writer.write(emcy(i), QueueLane::reliable));
  // Three fit the bus's queue; seven wait, more than the high watermark: backlogged.
  EXPECT_EQ(written.size(), 3u);
  EXPECT_EQ(writer.queue().waiting(), 7u);
  EXPECT_EQ(backlog_changes, std::vector<bool>{true});

  medium.release_held(2);  // two frames leave the bus: the writer fills the two slots
  ASSERT_TRUE(test::run_until(io, [&] { return written.size() == 5; }));
  EXPECT_EQ(writer.queue().waiting(), 5u);
  EXPECT_EQ(bus->send_room(), 0u);

  medium.hold(false);
  ASSERT_TRUE(test::run_until(io, [&] { return far.frames.size() == 10; }));
  for (std::uint8_t i = 0; i < 10; ++i) {
    EXPECT_EQ(far.frames[i], emcy(i)) << int{i};
    EXPECT_EQ(written[i], emcy(i)) << int{i};
  }
  EXPECT_EQ(backlog_changes, (std::vector<bool>{true, false}));
  EXPECT_EQ(writer.queue().counters().frames_waited, 7u);
  EXPECT_EQ(writer.queue().dropped(), 0u);
  EXPECT_EQ(bus->counters().tx_dropped_queue, 0u);  // the bus never had to refuse a frame
}

TEST_F(BusWriterTest, AFrameOfferedWhileOthersWaitNeverGoesFirst) {
  medium.hold(true);
  for (std::uint8_t i = 0; i < 4; ++i) ASSERT_TRUE(writer.write(emcy(i), QueueLane::reliable));
  medium.release_held(3);  // room for three, but the writer has not run yet
  ASSERT_TRUE(writer.write(emcy(4), QueueLane::reliable));
  EXPECT_EQ(written.size(), 3u);  // emcy(4) did not take the room ahead of emcy(3)
  medium.hold(false);
  ASSERT_TRUE(test::run_until(io, [&] { return far.frames.size() == 5; }));
  for (std::uint8_t i = 0; i < 5; ++i) EXPECT_EQ(far.frames[i], emcy(i)) << int{i};
}

// A writer whose bus is gone must not end in silence: its role stops (coro::spawn_owned).
TEST_F(BusWriterTest, ClosingTheBusEndsTheWriterAndItsOwnerHearsWhy) {
  std::vector<std::string> ends;
  writer.on_end([&](const std::string& why) { ends.push_back(why); });
  medium.hold(true);
  for (std::uint8_t i = 0; i < 5; ++i) ASSERT_TRUE(writer.write(emcy(i), QueueLane::reliable));
  bus->close();
  ASSERT_TRUE(test::run_until(io, [&] { return !ends.empty(); }));
  EXPECT_EQ(ends, (std::vector<std::string>{"the bus closed"}));
}

TEST_F(BusWriterTest, ClosingTheBusDropsWhatWaitsAndCountsIt) {
  medium.hold(true);
  for (std::uint8_t i = 0; i < 5; ++i) ASSERT_TRUE(writer.write(emcy(i), QueueLane::reliable));
  bus->close();
  ASSERT_TRUE(test::run_until(io, [&] { return writer.queue().empty(); }));
  EXPECT_EQ(
      writer.queue().counters().dropped[static_cast<std::size_t>(BusWriteQueue::Drop::closed)], 2u);
}

// A backbone message's frames go to the bus with one batch send and one Written call (the roles
// read the clock once per call), in order, with what does not fit waiting behind.
TEST_F(BusWriterTest, ARunGoesWithOneWrittenCallAndTheRestWaitsInOrder) {
  std::vector<std::size_t> calls;
  BusWriter counting{io.get_executor(),
                     *bus,
                     BusWriteQueue::Options{},
                     [&](std::span<const can::Frame> frames) {
                       calls.push_back(frames.size());
                       written.insert(written.end(), frames.begin(), frames.end());
                     },
                     {}};
  counting.start();
  std::vector<can::Frame> run;
  for (std::uint8_t i = 0; i < 7; ++i) run.push_back(emcy(i));
  medium.hold(true);
  EXPECT_EQ(counting.write_each(run), 0u);
  EXPECT_EQ(calls, std::vector<std::size_t>{3});  // the bus's three slots, in one call
  EXPECT_EQ(counting.queue().waiting(), 4u);
  medium.hold(false);
  ASSERT_TRUE(test::run_until(io, [&] { return far.frames.size() == 7; }));
  for (std::uint8_t i = 0; i < 7; ++i) EXPECT_EQ(far.frames[i], emcy(i)) << int{i};
  EXPECT_EQ(written, far.frames);
  counting.stop();
  io.poll();
}

// Issue 17: a long stream of process data from the backbone into a bus slower than the link.
// The link delivers whole messages of the largest size an outbox builds, the next one only while
// the writer's owner has not paused it (as a StreamLink does); the bus takes 300 frames per turn
// of the loop. The pause engages before any drop: backbone_fed_write_options() leaves room for the
// rest of the message that crossed the high watermark.
TEST(BusWriterBackpressure, AStreamOf100000ProcessFramesIntoASlowBusPausesAndDropsNothing) {
  constexpr std::uint32_t kFrames = 100'000;
  boost::asio::io_context io{1};
  can::VirtualBus medium{io.get_executor(), "slow"};
  std::unique_ptr<can::Bus> bus = medium.connect("writer", 256);
  test::BusRecorder far{io, medium.connect("far")};
  bool paused = false;
  std::uint64_t pauses = 0;
  BusWriter writer{io.get_executor(), *bus, backbone_fed_write_options(),
                   [](std::span<const can::Frame>) {},
                   [&](bool backlogged) {
                     paused = backlogged;
                     if (backlogged) ++pauses;
                   }};
  writer.start();
  medium.hold(true);
  auto tpdo = [](std::uint32_t seq) {
    return can::Frame::standard(
        0x185, {static_cast<std::uint8_t>(seq), static_cast<std::uint8_t>(seq >> 8),
                static_cast<std::uint8_t>(seq >> 16)});
  };
  ASSERT_EQ(bus_lane_of(tpdo(0)), QueueLane::process_data);
  std::uint32_t next = 0;
  std::vector<can::Frame> message;
  std::size_t dropped = 0;
  for (int turn = 0; turn < 10'000 && far.frames.size() < kFrames; ++turn) {
    while (!paused && next < kFrames) {
      message.clear();
      while (message.size() < kMaxFramesPerBackboneMessage && next < kFrames) {
        message.push_back(tpdo(next++));
      }
      dropped += writer.write_each(message);
    }
    medium.release_held(300);
    io.poll();
  }
  EXPECT_EQ(dropped, 0u);
  EXPECT_EQ(writer.queue().dropped(), 0u);
  EXPECT_GT(pauses, 1u);
  ASSERT_EQ(far.frames.size(), kFrames);
  for (std::uint32_t i = 0; i < kFrames; ++i) ASSERT_EQ(far.frames[i], tpdo(i)) << i;
  writer.stop();
  bus->close();
  far.close();
  EXPECT_TRUE(test::run_until(io, [&] { return far.done(); }));
}

}  // namespace
}  // namespace canbridge::bridge
