// The simulated minimal node (seeds/002_4fa7eeff27db9735.txt, MicroCANopen), frame by frame with
// an injected clock.
#include "sim/responder_node.hpp"

#include <gtest/gtest.h>

#include <stdexcept>

namespace canbridge::sim {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Frames = std::vector<Frame>;
using TimePoint = ResponderNode::TimePoint;
using canopen::NmtState;

const TimePoint t0 = TimePoint{} + 1h;

ResponderConfig config(canopen::NodeId id = 3) {
  ResponderConfig c;
  c.node_id = id;
  c.device_type = 0x00000191;
  c.identity = {0x000001A2, 0x00001234, 0x00010002, 0xCAFEF00D};
  c.heartbeat_ms = 1000;
  return c;
}

Frame nmt(std::uint8_t command, std::uint8_t node) {
  return Frame::standard(0x000, {command, node});
}

Frame upload(canopen::NodeId node, std::uint16_t index, std::uint8_t sub) {
  return Frame::standard(0x600 + node, {0x40, static_cast<std::uint8_t>(index),
                                        static_cast<std::uint8_t>(index >> 8), sub, 0, 0, 0, 0});
}

Frame abort_frame(canopen::NodeId node, std::uint16_t index, std::uint8_t sub, std::uint32_t code) {
  return Frame::standard(
      0x580 + node, {0x80, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8),
                     sub, static_cast<std::uint8_t>(code), static_cast<std::uint8_t>(code >> 8),
                     static_cast<std::uint8_t>(code >> 16), static_cast<std::uint8_t>(code >> 24)});
}

// A booted node with the boot-up already consumed.
struct Booted {
  explicit Booted(ResponderConfig c = config()) : node(c) {
    EXPECT_EQ(node.boot(t0), Frames{Frame::standard(0x700 + c.node_id, {0x00})});
  }
  Frames heartbeat_at(TimePoint now) { return node.on_tick(now); }
  ResponderNode node;
};

TEST(ResponderNode, SilentUntilBootThenBootUpAndPreOperational) {
  ResponderNode node(config(3));
  EXPECT_EQ(node.state(), NmtState::boot_up);
  EXPECT_TRUE(node.on_frame(upload(3, 0x1000, 0), t0).empty());
  EXPECT_TRUE(node.on_tick(t0 + 1h).empty());
  EXPECT_EQ(node.next_deadline(), TimePoint::max());

  EXPECT_EQ(node.boot(t0), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(node.state(), NmtState::pre_operational);
}

TEST(ResponderNode, RejectsNodeIdsOutsideOneTo127) {
  EXPECT_THROW(ResponderNode{config(0)}, std::invalid_argument);
  EXPECT_THROW(ResponderNode{config(128)}, std::invalid_argument);
  EXPECT_NO_THROW(ResponderNode{config(127)});
}

TEST(ResponderNode, HeartbeatEveryPeriodWithTheStateByte) {
  Booted b;
  EXPECT_EQ(b.node.next_deadline(), t0 + 1000ms);
  EXPECT_TRUE(b.heartbeat_at(t0 + 999ms).empty());
  EXPECT_EQ(b.heartbeat_at(t0 + 1000ms), Frames{Frame::standard(0x703, {0x7F})});
  EXPECT_TRUE(b.heartbeat_at(t0 + 1000ms).empty());  // a second call at the same time: nothing
  EXPECT_EQ(b.node.next_deadline(), t0 + 2000ms);
  // A late wake-up keeps the cadence...
  EXPECT_EQ(b.heartbeat_at(t0 + 2010ms).size(), 1u);
  EXPECT_EQ(b.node.next_deadline(), t0 + 3000ms);
  // ...and a long stall gives one heartbeat, not a burst.
  EXPECT_EQ(b.heartbeat_at(t0 + 10500ms).size(), 1u);
  EXPECT_EQ(b.node.next_deadline(), t0 + 11500ms);
}

TEST(ResponderNode, HeartbeatPeriodFollows1017hWrites) {
  Booted b;
  // Expedited download of 1017h = 100 ms.
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0}),
                            t0 + 10ms),
            Frames{Frame::standard(0x583, {0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0})});
  EXPECT_EQ(b.node.heartbeat_period(), 100ms);
  EXPECT_EQ(b.node.next_deadline(), t0 + 110ms);
  EXPECT_EQ(b.heartbeat_at(t0 + 110ms).size(), 1u);
  EXPECT_EQ(b.node.next_deadline(), t0 + 210ms);

  // Reading it back gives the new value.
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1017, 0), t0 + 120ms),
            Frames{Frame::standard(0x583, {0x4B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0})});

  // 0 disables the heartbeat.
  EXPECT_EQ(
      b.node.on_frame(Frame::standard(0x603, {0x2B, 0x17, 0x10, 0x00, 0, 0, 0, 0}), t0 + 150ms)
          .size(),
      1u);
  EXPECT_EQ(b.node.next_deadline(), TimePoint::max());
  EXPECT_TRUE(b.heartbeat_at(t0 + 1h).empty());
}

TEST(ResponderNode, ExpeditedDownloadWithoutSizeUsesTheObjectLength) {
  Booted b;
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x22, 0x17, 0x10, 0x00, 0xF4, 0x01, 0, 0}), t0),
            Frames{Frame::standard(0x583, {0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0})});
  EXPECT_EQ(b.node.heartbeat_period(), 500ms);
}

TEST(ResponderNode, NmtStartStopAndPreOperationalChangeTheHeartbeatState) {
  Booted b;
  EXPECT_TRUE(b.node.on_frame(nmt(0x01, 3), t0).empty());  // NMT produces no reply
  EXPECT_EQ(b.node.state(), NmtState::operational);
  EXPECT_EQ(b.heartbeat_at(t0 + 1s), Frames{Frame::standard(0x703, {0x05})});

  b.node.on_frame(nmt(0x02, 3), t0 + 1s);
  EXPECT_EQ(b.heartbeat_at(t0 + 2s), Frames{Frame::standard(0x703, {0x04})});

  b.node.on_frame(nmt(0x80, 3), t0 + 2s);
  EXPECT_EQ(b.heartbeat_at(t0 + 3s), Frames{Frame::standard(0x703, {0x7F})});
}

TEST(ResponderNode, NmtForAnotherNodeIsIgnoredAndBroadcastApplies) {
  Booted b;
  b.node.on_frame(nmt(0x01, 4), t0);
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
  b.node.on_frame(nmt(0x01, 0), t0);
  EXPECT_EQ(b.node.state(), NmtState::operational);
  b.node.on_frame(nmt(0x02, 0), t0);
  EXPECT_EQ(b.node.state(), NmtState::stopped);
}

TEST(ResponderNode, MalformedAndUnknownNmtCommandsAreIgnored) {
  Booted b;
  b.node.on_frame(Frame::standard(0x000, {0x01}), t0);        // too short
  b.node.on_frame(Frame::standard(0x000, {0x01, 3, 0}), t0);  // too long
  b.node.on_frame(nmt(0x03, 3), t0);                          // no such command
  Frame rtr = nmt(0x01, 3);
  rtr.flags = can::FrameFlags::remote;
  b.node.on_frame(rtr, t0);
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
}

TEST(ResponderNode, ResetNodeEmitsBootUpAndRestoresObjects) {
  Booted b;
  b.node.on_frame(nmt(0x01, 3), t0);
  b.node.on_frame(Frame::standard(0x603, {0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0}), t0);
  ASSERT_EQ(b.node.heartbeat_period(), 100ms);

  EXPECT_EQ(b.node.on_frame(nmt(0x81, 3), t0 + 50ms), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
  EXPECT_EQ(b.node.heartbeat_period(), 1000ms);
  EXPECT_EQ(b.node.next_deadline(), t0 + 1050ms);
}

TEST(ResponderNode, ResetCommunicationEmitsBootUp) {
  Booted b;
  b.node.on_frame(nmt(0x02, 0), t0);
  EXPECT_EQ(b.node.on_frame(nmt(0x82, 0), t0), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
}

TEST(ResponderNode, AutoStartEntersOperationalAfterEveryBootUp) {
  ResponderConfig c = config(9);
  c.auto_start = true;
  Booted b(c);
  EXPECT_EQ(b.node.state(), NmtState::operational);
  EXPECT_EQ(b.heartbeat_at(t0 + 1s), Frames{Frame::standard(0x709, {0x05})});
  b.node.on_frame(nmt(0x81, 9), t0 + 1s);
  EXPECT_EQ(b.node.state(), NmtState::operational);
}

TEST(ResponderNode, UploadsDeviceTypeErrorRegisterAndIdentityExactly) {
  Booted b;
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1000, 0), t0),
            Frames{Frame::standard(0x583, {0x43, 0x00, 0x10, 0x00, 0x91, 0x01, 0x00, 0x00})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1001, 0), t0),
            Frames{Frame::standard(0x583, {0x4F, 0x01, 0x10, 0x00, 0x00, 0, 0, 0})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 0), t0),
            Frames{Frame::standard(0x583, {0x4F, 0x18, 0x10, 0x00, 0x04, 0, 0, 0})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 1), t0),
            Frames{Frame::standard(0x583, {0x43, 0x18, 0x10, 0x01, 0xA2, 0x01, 0x00, 0x00})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 2), t0),
            Frames{Frame::standard(0x583, {0x43, 0x18, 0x10, 0x02, 0x34, 0x12, 0x00, 0x00})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 3), t0),
            Frames{Frame::standard(0x583, {0x43, 0x18, 0x10, 0x03, 0x02, 0x00, 0x01, 0x00})});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 4), t0),
            Frames{Frame::standard(0x583, {0x43, 0x18, 0x10, 0x04, 0x0D, 0xF0, 0xFE, 0xCA})});
}

TEST(ResponderNode, ErrorRegisterSetByTheDeviceIsVisible) {
  Booted b;
  ASSERT_TRUE(b.node.dictionary().set_unsigned(0x1001, 0, 0x01));
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1001, 0), t0),
            Frames{Frame::standard(0x583, {0x4F, 0x01, 0x10, 0x00, 0x01, 0, 0, 0})});
}

TEST(ResponderNode, SdoErrorsAbortWithTheCiA301Codes) {
  Booted b;
  EXPECT_EQ(b.node.on_frame(upload(3, 0x2000, 0), t0),
            Frames{abort_frame(3, 0x2000, 0, 0x06020000)});
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1018, 5), t0),
            Frames{abort_frame(3, 0x1018, 5, 0x06090011)});
  // Write to read-only (1018h:01) and to constant (1000h).
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x23, 0x18, 0x10, 0x01, 1, 2, 3, 4}), t0),
            Frames{abort_frame(3, 0x1018, 1, 0x06010002)});
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x23, 0x00, 0x10, 0x00, 1, 2, 3, 4}), t0),
            Frames{abort_frame(3, 0x1000, 0, 0x06010002)});
  // 1017h is UNSIGNED16: a 4-byte write has the wrong length.
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x23, 0x17, 0x10, 0x00, 1, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0x1017, 0, 0x06070010)});
}

TEST(ResponderNode, SegmentedAndBlockRequestsAbortWith05040001) {
  Booted b;
  // Initiate segmented download (e = 0, s = 1, 10 bytes).
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x21, 0x17, 0x10, 0x00, 10, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0x1017, 0, 0x05040001)});
  // Upload segment request without a transfer: no object address to echo.
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x60, 0, 0, 0, 0, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0, 0, 0x05040001)});
  // Initiate block upload of 1018h:01.
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0xA4, 0x18, 0x10, 0x01, 0x7F, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0x1018, 1, 0x05040001)});
}

TEST(ResponderNode, SdoIsIgnoredWhileStoppedAndForOtherNodes) {
  Booted b;
  EXPECT_TRUE(b.node.on_frame(upload(4, 0x1000, 0), t0).empty());
  EXPECT_TRUE(b.node.on_frame(Frame::standard(0x583, {0x43, 0, 0x10, 0, 0, 0, 0, 0}), t0).empty());
  EXPECT_TRUE(b.node.on_frame(Frame::standard(0x603, {0x40, 0x00, 0x10}), t0).empty());  // short
  // A client abort needs no answer.
  EXPECT_TRUE(
      b.node.on_frame(Frame::standard(0x603, {0x80, 0, 0x10, 0, 0, 0, 0, 0x08}), t0).empty());

  b.node.on_frame(nmt(0x02, 3), t0);
  EXPECT_TRUE(b.node.on_frame(upload(3, 0x1000, 0), t0).empty());
  EXPECT_TRUE(
      b.node.on_frame(Frame::standard(0x603, {0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0}), t0)
          .empty());
  EXPECT_EQ(b.node.heartbeat_period(), 1000ms);

  b.node.on_frame(nmt(0x01, 3), t0);  // operational: SDO answers again
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1000, 0), t0).size(), 1u);
}

}  // namespace
}  // namespace canbridge::sim
