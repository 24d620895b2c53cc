// Frames the bridge wrote to a bus, read back from it, are recognised as echoes, once each, for a
// bounded time and in bounded memory; everything else passes.
#include "bridge/loop_guard.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using Clock = LoopGuard::Clock;

const can::Frame kRequest = can::Frame::standard(0x602, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});

TEST(LoopGuard, AWrittenFrameReadBackIsAnEchoOnce) {
  LoopGuard guard(500ms);
  const auto t0 = Clock::now();
  guard.wrote(kRequest, t0);
  EXPECT_TRUE(guard.is_echo(kRequest, t0 + 1ms));
  EXPECT_FALSE(guard.is_echo(kRequest, t0 + 2ms));  // the same frame again is a new one
  EXPECT_EQ(guard.echoes(), 1u);
}

TEST(LoopGuard, OnlyTheVeryFrameCounts) {
  LoopGuard guard;
  const auto t0 = Clock::now();
  guard.wrote(kRequest, t0);
  can::Frame other_data = kRequest;
  other_data.data[7] = 1;
  can::Frame other_id = kRequest;
  other_id.id = 0x603;
  can::Frame remote = kRequest;
  remote.flags = can::FrameFlags::remote;
  EXPECT_FALSE(guard.is_echo(other_data, t0));
  EXPECT_FALSE(guard.is_echo(other_id, t0));
  EXPECT_FALSE(guard.is_echo(remote, t0));
  can::Frame stamped = kRequest;  // timestamps are not part of a frame's identity
  stamped.timestamp = std::chrono::nanoseconds(123456789);
  EXPECT_TRUE(guard.is_echo(stamped, t0));
}

TEST(LoopGuard, AFrameWrittenTwiceMayComeBackTwice) {
  LoopGuard guard;
  const auto t0 = Clock::now();
  guard.wrote(kRequest, t0);
  guard.wrote(kRequest, t0 + 1ms);
  EXPECT_TRUE(guard.is_echo(kRequest, t0 + 2ms));
  EXPECT_TRUE(guard.is_echo(kRequest, t0 + 3ms));
  EXPECT_FALSE(guard.is_echo(kRequest, t0 + 4ms));
}

TEST(LoopGuard, MemoryFadesAfterTheWindowAndStaysBounded) {
  LoopGuard guard(100ms, 64);
  const auto t0 = Clock::now();
  guard.wrote(kRequest, t0);
  EXPECT_FALSE(guard.is_echo(kRequest, t0 + 101ms));  // a frame this late is the node's own
  for (std::uint32_t i = 0; i < 10000; ++i) {
    guard.wrote(can::Frame::standard(0x180 + (i % 64), {static_cast<std::uint8_t>(i)}), t0 + 200ms);
  }
  EXPECT_LE(guard.remembered(), 64u);
  // The newest writes are remembered, the oldest pushed out.
  EXPECT_TRUE(guard.is_echo(can::Frame::standard(0x180 + (9999 % 64), {9999 % 256}), t0 + 201ms));
  EXPECT_FALSE(guard.is_echo(can::Frame::standard(0x1A4, {100}), t0 + 201ms));  // last: i = 9828
  // An echoed entry pushed out later does not disturb a newer write of the same frame.
  LoopGuard small(1000ms, 2);
  small.wrote(kRequest, t0);
  EXPECT_TRUE(small.is_echo(kRequest, t0));
  small.wrote(kRequest, t0 + 1ms);
  small.wrote(can::Frame::standard(0x1, {}), t0 + 2ms);  // pushes the echoed entry out
  EXPECT_TRUE(small.is_echo(kRequest, t0 + 3ms));
}

}  // namespace
}  // namespace canbridge::bridge
