// The simulated nodes frame by frame with an injected clock: the behaviour every kind shares,
// shown on the minimal node (seeds/002_4fa7eeff27db9735.txt, MicroCANopen).
#include "sim/sim_node.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <optional>
#include <stdexcept>
#include <string>

#include "canopen/crc16.hpp"
#include "sim/firmware_image.hpp"

namespace canbridge::sim {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Frames = std::vector<Frame>;
using TimePoint = SimNode::TimePoint;
using canopen::NmtState;

const TimePoint t0 = TimePoint{} + 1h;

NodeSpec config(canopen::NodeId id = 3) {
  NodeSpec c;
  c.kind = NodeKind::microcanopen;
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
  explicit Booted(NodeSpec c = config()) : node(c) {
    EXPECT_EQ(node.boot(t0), Frames{Frame::standard(0x700 + c.node_id, {0x00})});
  }
  Frames heartbeat_at(TimePoint now) { return node.on_tick(now); }
  SimNode node;
};

TEST(SimNode, SilentUntilBootThenBootUpAndPreOperational) {
  SimNode node(config(3));
  EXPECT_EQ(node.state(), NmtState::boot_up);
  EXPECT_TRUE(node.on_frame(upload(3, 0x1000, 0), t0).empty());
  EXPECT_TRUE(node.on_tick(t0 + 1h).empty());
  EXPECT_EQ(node.next_deadline(), TimePoint::max());

  EXPECT_EQ(node.boot(t0), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(node.state(), NmtState::pre_operational);
}

TEST(SimNode, RejectsNodeIdsOutsideOneTo127) {
  EXPECT_THROW(SimNode{config(0)}, std::invalid_argument);
  EXPECT_THROW(SimNode{config(128)}, std::invalid_argument);
  EXPECT_NO_THROW(SimNode{config(127)});
}

TEST(SimNode, HeartbeatEveryPeriodWithTheStateByte) {
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

TEST(SimNode, HeartbeatPeriodFollows1017hWrites) {
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

TEST(SimNode, ExpeditedDownloadWithoutSizeUsesTheObjectLength) {
  Booted b;
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x22, 0x17, 0x10, 0x00, 0xF4, 0x01, 0, 0}), t0),
            Frames{Frame::standard(0x583, {0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0})});
  EXPECT_EQ(b.node.heartbeat_period(), 500ms);
}

TEST(SimNode, NmtStartStopAndPreOperationalChangeTheHeartbeatState) {
  Booted b;
  EXPECT_TRUE(b.node.on_frame(nmt(0x01, 3), t0).empty());  // NMT produces no reply
  EXPECT_EQ(b.node.state(), NmtState::operational);
  EXPECT_EQ(b.heartbeat_at(t0 + 1s), Frames{Frame::standard(0x703, {0x05})});

  b.node.on_frame(nmt(0x02, 3), t0 + 1s);
  EXPECT_EQ(b.heartbeat_at(t0 + 2s), Frames{Frame::standard(0x703, {0x04})});

  b.node.on_frame(nmt(0x80, 3), t0 + 2s);
  EXPECT_EQ(b.heartbeat_at(t0 + 3s), Frames{Frame::standard(0x703, {0x7F})});
}

TEST(SimNode, NmtForAnotherNodeIsIgnoredAndBroadcastApplies) {
  Booted b;
  b.node.on_frame(nmt(0x01, 4), t0);
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
  b.node.on_frame(nmt(0x01, 0), t0);
  EXPECT_EQ(b.node.state(), NmtState::operational);
  b.node.on_frame(nmt(0x02, 0), t0);
  EXPECT_EQ(b.node.state(), NmtState::stopped);
}

TEST(SimNode, MalformedAndUnknownNmtCommandsAreIgnored) {
  Booted b;
  b.node.on_frame(Frame::standard(0x000, {0x01}), t0);        // too short
  b.node.on_frame(Frame::standard(0x000, {0x01, 3, 0}), t0);  // too long
  b.node.on_frame(nmt(0x03, 3), t0);                          // no such command
  Frame rtr = nmt(0x01, 3);
  rtr.flags = can::FrameFlags::remote;
  b.node.on_frame(rtr, t0);
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
}

TEST(SimNode, ResetNodeEmitsBootUpAndRestoresObjects) {
  Booted b;
  b.node.on_frame(nmt(0x01, 3), t0);
  b.node.on_frame(Frame::standard(0x603, {0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0}), t0);
  ASSERT_EQ(b.node.heartbeat_period(), 100ms);

  EXPECT_EQ(b.node.on_frame(nmt(0x81, 3), t0 + 50ms), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
  EXPECT_EQ(b.node.heartbeat_period(), 1000ms);
  EXPECT_EQ(b.node.next_deadline(), t0 + 1050ms);
}

TEST(SimNode, ResetCommunicationEmitsBootUp) {
  Booted b;
  b.node.on_frame(nmt(0x02, 0), t0);
  EXPECT_EQ(b.node.on_frame(nmt(0x82, 0), t0), Frames{Frame::standard(0x703, {0x00})});
  EXPECT_EQ(b.node.state(), NmtState::pre_operational);
}

TEST(SimNode, AutoStartEntersOperationalAfterEveryBootUp) {
  NodeSpec c = config(9);
  c.auto_start = true;
  Booted b(c);
  EXPECT_EQ(b.node.state(), NmtState::operational);
  EXPECT_EQ(b.heartbeat_at(t0 + 1s), Frames{Frame::standard(0x709, {0x05})});
  b.node.on_frame(nmt(0x81, 9), t0 + 1s);
  EXPECT_EQ(b.node.state(), NmtState::operational);
}

TEST(SimNode, UploadsDeviceTypeErrorRegisterAndIdentityExactly) {
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

TEST(SimNode, ErrorRegisterSetByTheDeviceIsVisible) {
  Booted b;
  ASSERT_TRUE(b.node.dictionary().set_unsigned(0x1001, 0, 0x01));
  EXPECT_EQ(b.node.on_frame(upload(3, 0x1001, 0), t0),
            Frames{Frame::standard(0x583, {0x4F, 0x01, 0x10, 0x00, 0x01, 0, 0, 0})});
}

TEST(SimNode, SdoErrorsAbortWithTheCiA301Codes) {
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
  // 1017h is UNSIGNED16: a 4-byte write is too long.
  EXPECT_EQ(b.node.on_frame(Frame::standard(0x603, {0x23, 0x17, 0x10, 0x00, 1, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0x1017, 0, 0x06070012)});
}

TEST(SimNode, SegmentedAndBlockRequestsAbortWith05040001) {
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

TEST(SimNode, SdoIsIgnoredWhileStoppedAndForOtherNodes) {
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

// ---- the kinds ---------------------------------------------------------------------------

Frame download4(canopen::NodeId node, std::uint16_t index, std::uint8_t sub, std::uint32_t v,
                std::uint8_t size) {
  const std::uint8_t command = static_cast<std::uint8_t>(0x23 | ((4 - size) << 2));
  return Frame::standard(
      0x600 + node,
      {command, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
       static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
       static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)});
}

// The 4 data bytes of an expedited upload response, or nullopt if the reply is something else.
std::optional<std::uint32_t> expedited_value(const Frames& replies) {
  if (replies.size() != 1 || (replies[0].data[0] & 0xE3) != 0x43) return std::nullopt;
  const auto& d = replies[0].data;
  return static_cast<std::uint32_t>(d[4]) | static_cast<std::uint32_t>(d[5]) << 8 |
         static_cast<std::uint32_t>(d[6]) << 16 | static_cast<std::uint32_t>(d[7]) << 24;
}

// A CiA 301 block download client driven frame by frame against the node: returns the frames
// the node sent that were not part of the transfer protocol (e.g. an EMCY), fails the test on
// any protocol error.
Frames block_download(SimNode& node, TimePoint now, std::uint16_t index, std::uint8_t sub,
                      const std::vector<std::uint8_t>& data) {
  const canopen::NodeId id = node.id();
  const auto size = static_cast<std::uint32_t>(data.size());
  auto replies = node.on_frame(
      Frame::standard(
          0x600 + id,
          {0xC6, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
           static_cast<std::uint8_t>(size), static_cast<std::uint8_t>(size >> 8),
           static_cast<std::uint8_t>(size >> 16), static_cast<std::uint8_t>(size >> 24)}),
      now);
  EXPECT_EQ(replies.size(), 1u);
  if (replies.size() != 1 || replies[0].data[0] != 0xA4) {
    ADD_FAILURE() << "block download not accepted";
    return {};
  }
  unsigned blksize = replies[0].data[4];
  std::size_t offset = 0;
  std::uint8_t last_n = 0;
  while (offset < data.size()) {
    Frames acks;
    for (unsigned seq = 1; seq <= blksize && offset < data.size(); ++seq) {
      std::array<std::uint8_t, 8> seg{};
      const std::size_t chunk = std::min<std::size_t>(7, data.size() - offset);
      std::copy_n(data.begin() + static_cast<std::ptrdiff_t>(offset), chunk, seg.begin() + 1);
      offset += chunk;
      const bool last = offset == data.size();
      if (last) last_n = static_cast<std::uint8_t>(7 - chunk);
      seg[0] = static_cast<std::uint8_t>(seq | (last ? 0x80 : 0));
      acks = node.on_frame(Frame::from_span(0x600 + id, seg), now);
      if (last || seq == blksize) break;
      EXPECT_TRUE(acks.empty());
    }
    EXPECT_EQ(acks.size(), 1u);
    if (acks.size() != 1 || acks[0].data[0] != 0xA2) return {};
    blksize = acks[0].data[2];
  }
  // End: ccs 6, n unused bytes, cs 1, CRC-16/XMODEM of the data.
  const std::uint16_t crc = canopen::crc16_xmodem(data);
  auto end = node.on_frame(
      Frame::standard(0x600 + id, {static_cast<std::uint8_t>(0xC1 | (last_n << 2)),
                                   static_cast<std::uint8_t>(crc),
                                   static_cast<std::uint8_t>(crc >> 8), 0, 0, 0, 0, 0}),
      now);
  Frames others;
  bool confirmed = false;
  for (const auto& f : end) {
    if (f.id == 0x580u + id && f.data[0] == 0xA1) {
      confirmed = true;
    } else {
      others.push_back(f);
    }
  }
  EXPECT_TRUE(confirmed);
  return others;
}

NodeSpec qd_spec(canopen::NodeId id = 4) {
  NodeSpec c;
  c.kind = NodeKind::qd;
  c.node_id = id;
  c.identity = {0x0000AA55, 0x00000300, 0x00010000, 0x00004711};
  c.heartbeat_ms = 500;
  return c;
}

TEST(QdNode, PowerOnShowsTheLoaderThenTheApplicationBootUp) {
  SimNode node(qd_spec(4));
  EXPECT_EQ(node.boot(t0), (Frames{Frame::standard(0x724, {0}), Frame::standard(0x704, {0})}));
  EXPECT_FALSE(node.in_loader());
  EXPECT_EQ(node.state(), NmtState::pre_operational);
  // Device type: profile 0, version in the high 16 bits.
  EXPECT_EQ(expedited_value(node.on_frame(upload(4, 0x1000, 0), t0)), 0x00010000u);
  // Reset node: back through the loader.
  EXPECT_EQ(node.on_frame(nmt(0x81, 4), t0),
            (Frames{Frame::standard(0x724, {0}), Frame::standard(0x704, {0})}));
  EXPECT_EQ(node.counters().loader_entries, 2u);
}

TEST(QdNode, RejectsIdsAbove31AndDeviceTypesWithAProfile) {
  EXPECT_THROW(SimNode(qd_spec(32)), std::invalid_argument);
  NodeSpec c = qd_spec(1);
  c.device_type = 0x00010191;
  EXPECT_THROW(SimNode{c}, std::invalid_argument);
}

TEST(QdNode, ExtendedConnectionSetTpdo34IsOnTheLastSdoImage) {
  NodeSpec c = qd_spec(5);
  c.objects.push_back({0x6000, 1, DataType::unsigned16, Access::ro, {0x34, 0x12}});
  PdoSpec tpdo;
  tpdo.number = 34;
  tpdo.event_timer_ms = 100;
  tpdo.mapping = {{0x6000, 1, 16}};
  c.tpdos.push_back(tpdo);
  c.auto_start = true;
  SimNode node(c);
  const Frames boot = node.boot(t0);
  const Frame expected = Frame::standard(0x665, {0x34, 0x12});
  EXPECT_NE(std::find(boot.begin(), boot.end(), expected), boot.end());
  EXPECT_EQ(node.on_tick(t0 + 100ms), Frames{expected});
  // Bit 31 may be set (the PDO stops), but the COB-ID itself is fixed.
  EXPECT_EQ(node.on_frame(download4(5, 0x1821, 1, 0x80000665, 4), t0 + 110ms).size(), 1u);
  EXPECT_TRUE(node.on_tick(t0 + 200ms).empty());
  const auto refused = node.on_frame(download4(5, 0x1821, 1, 0x80000123, 4), t0 + 210ms);
  ASSERT_EQ(refused.size(), 1u);
  EXPECT_EQ(refused[0].data[0], 0x80);
}

TEST(QdNode, GoodImageByBlockDownloadThenStart) {
  NodeSpec c = qd_spec(6);
  c.loader.wait_for_command = true;
  SimNode node(c);
  EXPECT_EQ(node.boot(t0), Frames{Frame::standard(0x726, {0})});
  ASSERT_TRUE(node.in_loader());
  // The loader has no application objects and sends no heartbeat.
  EXPECT_EQ(node.on_frame(upload(6, 0x1017, 0), t0), Frames{abort_frame(6, 0x1017, 0, 0x06020000)});
  EXPECT_EQ(node.next_deadline(), TimePoint::max());

  std::vector<std::uint8_t> application(3000);
  for (std::size_t i = 0; i < application.size(); ++i)
    application[i] = static_cast<std::uint8_t>(i * 7);
  const auto image = firmware::make_image(application);
  EXPECT_TRUE(block_download(node, t0, 0x1F50, 1, image).empty());
  EXPECT_EQ(expedited_value(node.on_frame(upload(6, 0x1F57, 1), t0)), 0u);
  EXPECT_EQ(expedited_value(node.on_frame(upload(6, 0x1F56, 1), t0)), firmware::crc32(application));
  EXPECT_EQ(node.on_frame(download4(6, 0x1F51, 1, 1, 1), t0),
            (Frames{Frame::standard(0x586, {0x60, 0x51, 0x1F, 0x01, 0, 0, 0, 0}),
                    Frame::standard(0x706, {0})}));
  EXPECT_FALSE(node.in_loader());
  EXPECT_EQ(node.counters().images_accepted, 1u);
  // The application reports the new image's identification.
  EXPECT_EQ(expedited_value(node.on_frame(upload(6, 0x1F56, 1), t0)), firmware::crc32(application));
}

TEST(QdNode, CorruptImageStaysInTheLoaderAndRaisesEmcy) {
  SimNode node(qd_spec(7));
  node.boot(t0);
  // The running application is told to stop: back to the loader, which waits.
  EXPECT_EQ(node.on_frame(download4(7, 0x1F51, 1, 0, 1), t0),
            (Frames{Frame::standard(0x587, {0x60, 0x51, 0x1F, 0x01, 0, 0, 0, 0}),
                    Frame::standard(0x727, {0})}));
  ASSERT_TRUE(node.in_loader());
  std::vector<std::uint8_t> application(500, 0x5A);
  auto image = firmware::make_image(application);
  image[100] ^= 0x01;  // one flipped bit
  EXPECT_EQ(block_download(node, t0, 0x1F50, 1, image),
            Frames{Frame::standard(0x87, {0x00, 0x62, 0x01, 'C', 'R', 'C', 0, 0})});
  EXPECT_EQ(expedited_value(node.on_frame(upload(7, 0x1F57, 1), t0)), 1u);
  EXPECT_EQ(node.on_frame(download4(7, 0x1F51, 1, 1, 1), t0),
            Frames{abort_frame(7, 0x1F51, 1, 0x08000022)});
  // NMT start cannot leave the loader either; only a good image can.
  EXPECT_TRUE(node.on_frame(nmt(0x01, 7), t0).empty());
  EXPECT_TRUE(node.in_loader());
  EXPECT_EQ(node.counters().images_rejected, 1u);
  // Power cycle (reset node) with the bad image: the loader stays.
  EXPECT_EQ(node.on_frame(nmt(0x81, 7), t0), Frames{Frame::standard(0x727, {0})});
}

TEST(QdNode, SubsystemEventIsAnFxxxhEmcy) {
  SimNode node(qd_spec(3));
  node.boot(t0);
  const Frames emcy = node.flag_subsystem(2, t0);
  ASSERT_EQ(emcy.size(), 1u);
  EXPECT_EQ(emcy[0].id, 0x83u);
  EXPECT_EQ(emcy[0].data[0], 0x04);
  EXPECT_EQ(emcy[0].data[1], 0xF0);
  EXPECT_TRUE(node.flag_subsystem(2, t0 + 1s).empty());  // not re-armed yet
}

NodeSpec fpga_spec(canopen::NodeId id = 5) {
  NodeSpec c;
  c.kind = NodeKind::fpga;
  c.node_id = id;
  c.identity = {0x0000AA55, 0x00000200, 0x00010000, 0xCDAB3412};
  c.heartbeat_ms = 200;
  c.objects.push_back({0x6000, 1, DataType::unsigned32, Access::ro, {1, 2, 3, 4}});
  c.objects.push_back({0x6200, 1, DataType::unsigned32, Access::rw, {0, 0, 0, 0}});
  PdoSpec tpdo;
  tpdo.number = 1;
  tpdo.mapping = {{0x6000, 1, 32}};
  c.tpdos.push_back(tpdo);
  PdoSpec rpdo;
  rpdo.number = 1;
  rpdo.mapping = {{0x6200, 1, 32}};
  c.rpdos.push_back(rpdo);
  return c;
}

TEST(FpgaNode, RenameByIdAndBySerialBootsUpOnTheNewId) {
  SimNode node(fpga_spec(5));
  node.boot(t0);
  EXPECT_EQ(node.on_frame(Frame::standard(0x000, {0xE0, 0x05, 0x09}), t0),
            Frames{Frame::standard(0x709, {0})});
  EXPECT_EQ(node.id(), 9);
  EXPECT_TRUE(node.on_frame(upload(5, 0x1000, 0), t0).empty());
  EXPECT_EQ(expedited_value(node.on_frame(upload(9, 0x1014, 0), t0)), 0x89u);
  EXPECT_EQ(node.on_tick(t0 + 200ms), Frames{Frame::standard(0x709, {0x7F})});
  // Malformed or out-of-range renames change nothing.
  EXPECT_TRUE(node.on_frame(Frame::standard(0x000, {0xE0, 0x09, 0x20}), t0).empty());
  EXPECT_TRUE(node.on_frame(Frame::standard(0x000, {0xE0, 0x09}), t0).empty());
  EXPECT_TRUE(node.on_frame(Frame::standard(0x000, {0xE0, 0x07, 0x03}), t0).empty());
  EXPECT_EQ(node.id(), 9);
  // By serial number 0xCDAB3412, little-endian.
  EXPECT_EQ(node.on_frame(Frame::standard(0x000, {0xE1, 0x0C, 0x12, 0x34, 0xAB, 0xCD}), t0),
            Frames{Frame::standard(0x70C, {0})});
  // The id survives reset node.
  EXPECT_EQ(node.on_frame(nmt(0x81, 12), t0), Frames{Frame::standard(0x70C, {0})});
  EXPECT_EQ(node.counters().renames, 2u);
}

TEST(FpgaNode, SamplesGoOutAsPdoPacketsOnlyWhenOperational) {
  SimNode node(fpga_spec(5));
  node.boot(t0);
  std::vector<std::uint8_t> sample(20);
  for (std::size_t i = 0; i < sample.size(); ++i) sample[i] = static_cast<std::uint8_t>(i);
  EXPECT_TRUE(node.send_packet(1, sample, t0).empty());
  node.on_frame(nmt(0x01, 5), t0);
  // docs/pdop.md section 6, byte for byte.
  EXPECT_EQ(node.send_packet(1, sample, t0),
            (Frames{Frame::standard(0x1A5, {0, 1, 2, 3, 4, 5, 6, 7}),
                    Frame::standard(0x1E5, {8, 9, 10, 11, 12, 13, 14, 15}),
                    Frame::standard(0x185, {16, 17, 18, 19})}));
}

TEST(FpgaNode, ReceivesAPacketWithFlowControlAndCountsIt) {
  NodeSpec c = fpga_spec(3);
  c.pdop.window = 2;
  SimNode node(c);
  node.boot(t0);
  node.on_frame(nmt(0x01, 3), t0);
  EXPECT_TRUE(node.on_frame(Frame::standard(0x223, {1, 2, 3, 4, 5, 6, 7, 8}), t0).empty());
  EXPECT_EQ(node.on_frame(Frame::standard(0x263, {1, 2, 3, 4, 5, 6, 7, 8}), t0),
            Frames{Frame::standard(0x683, {1, 0, 2, 0, 2})});
  EXPECT_EQ(node.on_frame(Frame::standard(0x203, {9}), t0),
            Frames{Frame::standard(0x683, {1, 1, 3, 0, 2})});
  ASSERT_EQ(node.received_packets().size(), 1u);
  EXPECT_EQ(node.received_packets().back().bytes.size(), 17u);
  EXPECT_EQ(expedited_value(node.on_frame(upload(3, 0x5F00, 1), t0)), 1u);
  // Expedited only: a segmented request is refused.
  EXPECT_EQ(node.on_frame(Frame::standard(0x603, {0x21, 0x00, 0x62, 0x01, 10, 0, 0, 0}), t0),
            Frames{abort_frame(3, 0x6200, 1, 0x05040001)});
}

TEST(Cia301Node, SegmentedUploadOfAString) {
  NodeSpec c;
  c.kind = NodeKind::cia301;
  c.node_id = 100;
  const std::string text = "canbridge cia301 node";
  c.objects.push_back(
      {0x1008, 0, DataType::visible_string, Access::constant, {text.begin(), text.end()}});
  SimNode node(c);
  node.boot(t0);
  const auto init = node.on_frame(upload(100, 0x1008, 0), t0);
  ASSERT_EQ(init.size(), 1u);
  EXPECT_EQ(init[0].data[0], 0x41);  // segmented, size indicated
  EXPECT_EQ(init[0].data[4], text.size());
  std::string received;
  std::uint8_t toggle = 0;
  for (int i = 0; i < 10; ++i) {
    const auto seg = node.on_frame(
        Frame::standard(0x600 + 100,
                        {static_cast<std::uint8_t>(0x60 | toggle), 0, 0, 0, 0, 0, 0, 0}),
        t0);
    ASSERT_EQ(seg.size(), 1u);
    EXPECT_EQ(seg[0].data[0] & 0x10, toggle);
    const unsigned n = (seg[0].data[0] >> 1) & 0x7;
    received.append(seg[0].data.begin() + 1, seg[0].data.begin() + 8 - n);
    if (seg[0].data[0] & 0x01) break;
    toggle ^= 0x10;
  }
  EXPECT_EQ(received, text);
}

TEST(MicroCanopenNode, CounterTrafficDrivesAnEventTimerTpdo) {
  NodeSpec c = config(8);
  c.auto_start = true;
  c.objects.push_back({0x6000, 1, DataType::unsigned8, Access::ro, {0}});
  PdoSpec tpdo;
  tpdo.number = 1;
  tpdo.event_timer_ms = 100;
  tpdo.mapping = {{0x6000, 1, 8}};
  c.tpdos.push_back(tpdo);
  TrafficSpec counter;
  counter.kind = TrafficSpec::Kind::counter;
  counter.period = 100ms;
  counter.index = 0x6000;
  counter.sub = 1;
  c.traffic.push_back(counter);
  SimNode node(c);
  node.boot(t0);
  const auto at100 = node.on_tick(t0 + 100ms);
  EXPECT_NE(std::find(at100.begin(), at100.end(), Frame::standard(0x188, {1})), at100.end());
  // A change of state while the inhibit time is 0 goes out at once; the event timer continues.
  const auto at200 = node.on_tick(t0 + 200ms);
  EXPECT_NE(std::find(at200.begin(), at200.end(), Frame::standard(0x188, {2})), at200.end());
}

TEST(Cia301Node, ValueChangedBySdoOrRpdoGoesOutAtOnceAsChangeOfState) {
  NodeSpec c;
  c.kind = NodeKind::cia301;
  c.node_id = 20;
  c.auto_start = true;
  c.objects.push_back({0x2000, 0, DataType::unsigned16, Access::rw, {0, 0}});
  PdoSpec tpdo;
  tpdo.number = 1;
  tpdo.mapping = {{0x2000, 0, 16}};
  c.tpdos.push_back(tpdo);
  PdoSpec rpdo;
  rpdo.number = 1;
  rpdo.mapping = {{0x2000, 0, 16}};
  c.rpdos.push_back(rpdo);
  SimNode node(c);
  node.boot(t0);
  // Frames for other nodes change nothing and draw nothing.
  EXPECT_TRUE(node.on_frame(Frame::standard(0x215, {1, 2}), t0).empty());
  EXPECT_EQ(node.on_frame(download4(20, 0x2000, 0, 0x1234, 2), t0),
            (Frames{Frame::standard(0x594, {0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}),
                    Frame::standard(0x194, {0x34, 0x12})}));
  EXPECT_EQ(node.on_frame(Frame::standard(0x214, {0xCD, 0xAB}), t0),
            Frames{Frame::standard(0x194, {0xCD, 0xAB})});
  // The same value again is no change of state.
  EXPECT_TRUE(node.on_frame(Frame::standard(0x214, {0xCD, 0xAB}), t0).empty());
}

}  // namespace
}  // namespace canbridge::sim
