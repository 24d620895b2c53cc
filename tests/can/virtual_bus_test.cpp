#include "can/virtual_bus.hpp"

#include <gtest/gtest.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <limits>
#include <optional>

#include "tests/support/spawn_checked.hpp"

namespace canbridge::can {
namespace {

namespace asio = boost::asio;

std::vector<Frame> receive_all(asio::io_context& io, Bus& bus) {
  std::vector<Frame> out;
  std::error_code result = std::make_error_code(std::errc::operation_would_block);
  test::spawn_checked(io,
                      [&]() -> asio::awaitable<void> { result = co_await bus.receive_batch(out); });
  io.run();
  io.restart();
  EXPECT_FALSE(result) << result.message();
  return out;
}

TEST(VirtualBus, DeliversToEveryOtherEndpointInOrderWithoutEcho) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a");
  auto b = medium.connect("b");
  auto c = medium.connect("c");
  ASSERT_TRUE(a->send(Frame::standard(0x181, {1, 2})));
  ASSERT_TRUE(a->send(Frame::standard(0x182, {3})));
  auto at_b = receive_all(io, *b);
  auto at_c = receive_all(io, *c);
  ASSERT_EQ(at_b.size(), 2u);
  EXPECT_EQ(at_b[0], Frame::standard(0x181, {1, 2}));
  EXPECT_EQ(at_b[1], Frame::standard(0x182, {3}));
  EXPECT_EQ(at_c, at_b);
  EXPECT_EQ(a->counters().tx_frames, 2u);
  EXPECT_EQ(a->counters().rx_frames, 0u);  // never echoed to the sender
}

TEST(VirtualBus, ReceiveWaitsForAFrameSentLater) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a");
  auto b = medium.connect("b");
  std::vector<Frame> out;
  test::spawn_checked(io, [&]() -> asio::awaitable<void> { co_await b->receive_batch(out); });
  io.poll();
  EXPECT_TRUE(out.empty());
  a->send(Frame::standard(0x700, {0x05}));
  io.run();
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].data[0], 0x05);
  EXPECT_NE(out[0].timestamp.count(), 0);
}

TEST(VirtualBus, SendRoomIsUnboundedUntilClosed) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a");
  EXPECT_EQ(a->send_room(), std::numeric_limits<std::size_t>::max());
  a->close();
  EXPECT_EQ(a->send_room(), 0u);
}

TEST(VirtualBus, BoundedQueueCountsOverflowAndCloseEndsWait) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus", 2);
  auto a = medium.connect("a");
  auto b = medium.connect("b");
  for (int i = 0; i < 5; ++i) a->send(Frame::standard(0x100, {}));
  EXPECT_EQ(b->counters().rx_dropped_queue, 3u);
  const auto before = receive_all(io, *b);
  ASSERT_EQ(before.size(), 2u);
  EXPECT_FALSE(before[0].follows_loss());
  EXPECT_FALSE(before[1].follows_loss());
  // The first frame queued after the drops carries the loss mark, the next one does not.
  a->send(Frame::standard(0x101, {}));
  a->send(Frame::standard(0x102, {}));
  const auto after = receive_all(io, *b);
  ASSERT_EQ(after.size(), 2u);
  EXPECT_TRUE(after[0].follows_loss());
  EXPECT_FALSE(after[1].follows_loss());

  std::error_code ec;
  std::vector<Frame> out;
  test::spawn_checked(io, [&]() -> asio::awaitable<void> { ec = co_await b->receive_batch(out); });
  io.poll();
  b->close();
  io.run();
  EXPECT_EQ(ec, std::errc::operation_canceled);
}

TEST(Frame, FormatsLikeCansend) {
  EXPECT_EQ(to_string(Frame::standard(0x123, {0xDE, 0xAD})), "123#DEAD");
  Frame ext = Frame::from_span(0x12345678, std::array<std::uint8_t, 1>{1}, FrameFlags::extended);
  EXPECT_EQ(to_string(ext), "12345678#01");
  Frame rtr;
  rtr.id = 0x7FF;
  rtr.flags = FrameFlags::remote;
  EXPECT_EQ(to_string(rtr), "7FF#R");
}

// A held medium: sends wait in the sender's bounded transmit queue, as on a bus too busy to take
// them; a writer awaiting room learns of it when frames leave, without polling.
TEST(VirtualBus, HeldSendsQueueAndRoomWaitEndsWhenTheyLeave) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a", 3);
  auto b = medium.connect("b");
  EXPECT_EQ(a->send_room(), 3u);
  medium.hold(true);
  for (std::uint8_t i = 0; i < 3; ++i) ASSERT_TRUE(a->send(Frame::standard(0x601, {i})));
  EXPECT_EQ(a->send_room(), 0u);
  EXPECT_FALSE(a->send(Frame::standard(0x601, {9})));  // full: refused and counted
  EXPECT_EQ(a->counters().tx_dropped_queue, 1u);
  EXPECT_EQ(a->counters().tx_frames, 0u);

  std::optional<std::error_code> waited;
  test::spawn_checked(io,
                      [&]() -> asio::awaitable<void> { waited = co_await a->wait_send_room(2); });
  io.poll();
  EXPECT_FALSE(waited);
  medium.release_held(1);  // one slot free: not yet the two the writer waits for
  io.poll();
  EXPECT_FALSE(waited);
  EXPECT_EQ(a->send_room(), 1u);
  medium.release_held(1);
  io.poll();
  ASSERT_TRUE(waited);
  EXPECT_FALSE(*waited) << waited->message();
  EXPECT_EQ(a->send_room(), 2u);

  medium.hold(false);  // the rest goes, and later sends are immediate again
  ASSERT_TRUE(a->send(Frame::standard(0x601, {3})));
  io.restart();  // the loop ran out of work when the wait ended
  const auto at_b = receive_all(io, *b);
  ASSERT_EQ(at_b.size(), 4u);
  for (std::uint8_t i = 0; i < 4; ++i) EXPECT_EQ(at_b[i], Frame::standard(0x601, {i})) << int{i};
  EXPECT_EQ(a->counters().tx_frames, 4u);
}

// The batch send: the run is delivered in order, sharing one timestamp (one clock read); while
// the medium is held it queues behind what waits, taking only the prefix that fits.
TEST(VirtualBus, ABatchSendDeliversTheRunInOrderOrQueuesThePrefixThatFits) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a", 3);
  auto b = medium.connect("b");
  const std::vector<Frame> run = {Frame::standard(0x181, {1}), Frame::standard(0x281, {2}),
                                  Frame::standard(0x181, {3}), Frame::standard(0x381, {4})};
  EXPECT_EQ(a->send(std::span<const Frame>(run)), run.size());  // more than the queue: none waits
  auto at_b = receive_all(io, *b);
  ASSERT_EQ(at_b, run);
  for (const Frame& f : at_b) EXPECT_EQ(f.timestamp, at_b.front().timestamp);

  medium.hold(true);
  ASSERT_TRUE(a->send(Frame::standard(0x100, {0})));
  EXPECT_EQ(a->send(std::span<const Frame>(run)), 2u);  // two slots left: the first refusal ends it
  EXPECT_EQ(a->counters().tx_dropped_queue, 1u);
  medium.hold(false);
  at_b = receive_all(io, *b);
  ASSERT_EQ(at_b.size(), 3u);
  EXPECT_EQ(at_b[0], Frame::standard(0x100, {0}));
  EXPECT_EQ(at_b[1], run[0]);
  EXPECT_EQ(at_b[2], run[1]);
}

TEST(VirtualBus, RoomWaitIsImmediateWithRoomAndFailsOnClose) {
  asio::io_context io;
  VirtualBus medium(io.get_executor(), "vbus");
  auto a = medium.connect("a", 1);
  std::optional<std::error_code> first, second;
  test::spawn_checked(io,
                      [&]() -> asio::awaitable<void> { first = co_await a->wait_send_room(1); });
  io.poll();
  ASSERT_TRUE(first);
  EXPECT_FALSE(*first);
  io.restart();  // the loop ran out of work when the wait ended
  medium.hold(true);
  ASSERT_TRUE(a->send(Frame::standard(0x80, {})));
  test::spawn_checked(io,
                      [&]() -> asio::awaitable<void> { second = co_await a->wait_send_room(1); });
  io.poll();
  EXPECT_FALSE(second);
  a->close();  // the held frame is lost with the station, and counted
  io.poll();
  ASSERT_TRUE(second);
  EXPECT_TRUE(*second);
  EXPECT_EQ(a->counters().tx_dropped_error, 1u);
}

}  // namespace
}  // namespace canbridge::can
