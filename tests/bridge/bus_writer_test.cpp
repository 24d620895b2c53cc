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

using Lane = BusWriteQueue::Lane;

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
  for (std::uint8_t i = 0; i < 10; ++i) ASSERT_TRUE(writer.write(emcy(i), Lane::reliable));
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
  for (std::uint8_t i = 0; i < 4; ++i) ASSERT_TRUE(writer.write(emcy(i), Lane::reliable));
  medium.release_held(3);  // room for three, but the writer has not run yet
  ASSERT_TRUE(writer.write(emcy(4), Lane::reliable));
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
  for (std::uint8_t i = 0; i < 5; ++i) ASSERT_TRUE(writer.write(emcy(i), Lane::reliable));
  bus->close();
  ASSERT_TRUE(test::run_until(io, [&] { return !ends.empty(); }));
  EXPECT_EQ(ends, (std::vector<std::string>{"the bus closed"}));
}

TEST_F(BusWriterTest, ClosingTheBusDropsWhatWaitsAndCountsIt) {
  medium.hold(true);
  for (std::uint8_t i = 0; i < 5; ++i) ASSERT_TRUE(writer.write(emcy(i), Lane::reliable));
  bus->close();
  ASSERT_TRUE(test::run_until(io, [&] { return writer.queue().empty(); }));
  EXPECT_EQ(
      writer.queue().counters().dropped[static_cast<std::size_t>(BusWriteQueue::Drop::closed)], 2u);
}

}  // namespace
}  // namespace canbridge::bridge
