#include "canopen/pdop.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <numeric>
#include <stdexcept>
#include <vector>

#include "can/frame.hpp"
#include "sim/rpdop_receiver.hpp"

namespace canbridge::sim {
namespace {

namespace pdop = canopen::pdop;
using can::Frame;
using pdop::Ack;
using pdop::AckStatus;
using Bytes = std::vector<std::uint8_t>;
using namespace std::chrono_literals;

// 0, 1, 2, ... as in the worked examples, so a misplaced byte shows in the failure.
Bytes counting(std::size_t size, std::uint8_t first = 0) {
  Bytes bytes(size);
  std::iota(bytes.begin(), bytes.end(), first);
  return bytes;
}

Frame fragment_frame(std::uint16_t base, canopen::NodeId node, bool toggle, bool continued,
                     const Bytes& data) {
  const pdop::FragmentId id{static_cast<std::uint8_t>(base >> 7), toggle, continued, node};
  return Frame::from_span(pdop::encode(id), data);
}

Frame ack_frame(canopen::NodeId node, std::uint8_t rpdo, AckStatus status, std::uint16_t received,
                std::uint8_t credit) {
  return pdop::encode_ack(node, Ack{rpdo, status, received, credit});
}

// ---- Identifiers --------------------------------------------------------------------------------

TEST(PdopIds, EncodeDecodeRoundTripForEveryToggleAndContinued) {
  for (std::uint8_t code = 3; code <= 10; ++code) {
    for (const canopen::NodeId node : {canopen::NodeId{1}, canopen::NodeId{31}}) {
      for (const bool toggle : {false, true}) {
        for (const bool continued : {false, true}) {
          const pdop::FragmentId id{code, toggle, continued, node};
          const std::uint32_t cob_id = pdop::encode(id);
          EXPECT_EQ(cob_id, (std::uint32_t{code} << 7) | (toggle ? 0x40u : 0u) |
                                (continued ? 0x20u : 0u) | node);
          EXPECT_LE(cob_id, can::kMaxStandardId);
          EXPECT_EQ(pdop::decode(cob_id), id);
        }
      }
    }
  }
}

TEST(PdopIds, WorkedExampleIdentifiersOfNode5Tpdo1) {
  EXPECT_EQ(pdop::encode({3, false, false, 5}), 0x185u);
  EXPECT_EQ(pdop::encode({3, false, true, 5}), 0x1A5u);
  EXPECT_EQ(pdop::encode({3, true, false, 5}), 0x1C5u);
  EXPECT_EQ(pdop::encode({3, true, true, 5}), 0x1E5u);
  // t = c = 0 is the predefined connection set's PDO: a one-frame packet is a plain PDO.
  EXPECT_EQ(pdop::encode({4, false, false, 31}), canopen::cob::rpdo1 + 31u);
}

TEST(PdopIds, PdoBasesAndNumbers) {
  constexpr std::uint16_t tpdos[] = {0x180, 0x280, 0x380, 0x480};
  constexpr std::uint16_t rpdos[] = {0x200, 0x300, 0x400, 0x500};
  for (unsigned n = 1; n <= 4; ++n) {
    EXPECT_EQ(pdop::tpdo_base(n), tpdos[n - 1]);
    EXPECT_EQ(pdop::rpdo_base(n), rpdos[n - 1]);
    EXPECT_EQ(pdop::tpdo_number(static_cast<std::uint8_t>(tpdos[n - 1] >> 7)), n);
    EXPECT_EQ(pdop::rpdo_number(static_cast<std::uint8_t>(rpdos[n - 1] >> 7)), n);
    EXPECT_FALSE(pdop::rpdo_number(static_cast<std::uint8_t>(tpdos[n - 1] >> 7)));
    EXPECT_FALSE(pdop::tpdo_number(static_cast<std::uint8_t>(rpdos[n - 1] >> 7)));
  }
  EXPECT_EQ(pdop::tpdo_base(0), 0);
  EXPECT_EQ(pdop::rpdo_base(5), 0);
  for (const std::uint8_t code : {0, 1, 2, 11, 12, 13, 15}) {
    EXPECT_FALSE(pdop::tpdo_number(code)) << int{code};
    EXPECT_FALSE(pdop::rpdo_number(code)) << int{code};
  }
}

// ---- fragment() ---------------------------------------------------------------------------------

TEST(PdopFragment, WorkedExampleTwentyByteTpdopOfNode5) {
  const auto frames = pdop::fragment(pdop::tpdo_base(1), 5, counting(20));
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[0], Frame::standard(0x1A5, {0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07}));
  EXPECT_EQ(frames[1], Frame::standard(0x1E5, {0x08, 0x09, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F}));
  EXPECT_EQ(frames[2], Frame::standard(0x185, {0x10, 0x11, 0x12, 0x13}));
}

// Checks the section 2 table for every fragment and that the payloads concatenate to the packet.
void expect_fragments_of(const std::vector<Frame>& frames, std::uint16_t base, canopen::NodeId node,
                         const Bytes& packet) {
  const std::size_t n = (packet.size() + 7) / 8;
  ASSERT_EQ(frames.size(), n);
  Bytes joined;
  for (std::size_t k = 0; k < n; ++k) {
    const Frame& f = frames[k];
    const bool last = k + 1 == n;
    ASSERT_FALSE(f.is_remote() || f.is_extended()) << k;
    ASSERT_EQ(pdop::decode(f.id),
              (pdop::FragmentId{static_cast<std::uint8_t>(base >> 7), k % 2 == 1, !last, node}))
        << "fragment " << k;
    ASSERT_EQ(f.len, last ? packet.size() - 8 * (n - 1) : 8u) << "fragment " << k;
    joined.insert(joined.end(), f.payload().begin(), f.payload().end());
  }
  EXPECT_EQ(joined, packet);
}

TEST(PdopFragment, EdgeSizes) {
  for (const std::size_t size : {1u, 7u, 8u, 9u, 15u, 16u, 17u}) {
    SCOPED_TRACE(size);
    const Bytes packet = counting(size, 0x40);
    expect_fragments_of(pdop::fragment(0x300, 31, packet), 0x300, 31, packet);
  }
  EXPECT_EQ(pdop::fragment(0x200, 1, counting(1)),
            (std::vector<Frame>{Frame::standard(0x201, {0x00})}));
  EXPECT_EQ(pdop::fragment(0x200, 1, counting(8)).back().id, 0x201u);  // one frame: t = c = 0
  EXPECT_EQ(pdop::fragment(0x200, 1, counting(9)).back(), Frame::standard(0x241, {0x08}));
  EXPECT_EQ(pdop::fragment(0x200, 1, counting(17)).back(), Frame::standard(0x201, {0x10}));
}

TEST(PdopFragment, LargestPacketAndBeyond) {
  const Bytes largest(pdop::kMaxPacketBytes, 0xA5);
  const auto frames = pdop::fragment(0x480, 7, largest);
  expect_fragments_of(frames, 0x480, 7, largest);
  ASSERT_EQ(frames.size(), 65535u);
  EXPECT_EQ(frames.back().id, 0x487u);  // k = 65534: t = 0, c = 0

  EXPECT_TRUE(pdop::fragment(0x480, 7, Bytes(pdop::kMaxPacketBytes + 1)).empty());
  EXPECT_TRUE(pdop::fragment(0x480, 7, Bytes{}).empty());
}

TEST(PdopFragment, NoFramesForAnAddressNoPdopCanCarry) {
  const Bytes packet = counting(10);
  EXPECT_TRUE(pdop::fragment(0x200, 0, packet).empty());
  EXPECT_TRUE(pdop::fragment(0x200, 32, packet).empty());
  EXPECT_TRUE(pdop::fragment(0x580, 1, packet).empty());  // SDO, not a PDO
  EXPECT_TRUE(pdop::fragment(0x680, 1, packet).empty());
  EXPECT_TRUE(pdop::fragment(0x201, 1, packet).empty());  // not a base
  EXPECT_TRUE(pdop::fragment(0x000, 1, packet).empty());
}

// ---- Acknowledgement, request and abort frames
// ---------------------------------------------------

TEST(PdopAck, EncodesTheWorkedExampleBytes) {
  EXPECT_EQ(pdop::encode_ack(3, Ack{1, AckStatus::in_progress, 2, 2}),
            Frame::standard(0x683, {0x01, 0x00, 0x02, 0x00, 0x02}));
  EXPECT_EQ(pdop::encode_ack(3, Ack{1, AckStatus::complete, 3, 2}),
            Frame::standard(0x683, {0x01, 0x01, 0x03, 0x00, 0x02}));
  // received is little-endian.
  EXPECT_EQ(pdop::encode_ack(31, Ack{4, AckStatus::sender_abort, 0xFFFE, 255}),
            Frame::standard(0x69F, {0x04, 0x85, 0xFE, 0xFF, 0xFF}));
}

TEST(PdopAck, DecodeRoundTripsAndRejectsOtherFrames) {
  const Ack ack{2, AckStatus::timeout, 0x1234, 9};
  for (const canopen::NodeId node : {canopen::NodeId{1}, canopen::NodeId{31}}) {
    EXPECT_EQ(pdop::decode_ack(pdop::encode_ack(node, ack)), ack);
  }
  const auto data = Frame::standard(0x681, {0x01, 0x00, 0x00, 0x00, 0x04});
  EXPECT_TRUE(pdop::decode_ack(data));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x681, {0x01, 0x00, 0x00, 0x00})));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x681, {0x01, 0x00, 0x00, 0x00, 0x04, 0x00})));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x680, {0x01, 0x00, 0x00, 0x00, 0x04})));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x6A0, {0x01, 0x00, 0x00, 0x00, 0x04})));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x681, {0x00, 0x00, 0x00, 0x00, 0x04})));
  EXPECT_FALSE(pdop::decode_ack(Frame::standard(0x681, {0x05, 0x00, 0x00, 0x00, 0x04})));
  EXPECT_FALSE(pdop::decode_ack(
      Frame::make(0x681, can::FrameFlags::extended, {0x01, 0x00, 0x00, 0x00, 0x04})));
  EXPECT_FALSE(pdop::decode_ack(pdop::ack_request(1)));
}

TEST(PdopAck, RequestIsARemoteFrameAndAbortAnEmptyFrame) {
  const Frame request = pdop::ack_request(3);
  EXPECT_EQ(request.id, 0x683u);
  EXPECT_TRUE(request.is_remote());
  EXPECT_FALSE(request.is_extended());
  EXPECT_EQ(request.len, 5);

  EXPECT_EQ(pdop::abort_frame(0x200, 3), Frame::standard(0x203, {}));
  EXPECT_EQ(pdop::abort_frame(0x500, 31), Frame::standard(0x51F, {}));
}

// ---- RpdopReceiver ------------------------------------------------------------------------------

// Feeds one frame at a time at an injected time; each feed starts with empty outputs.
class Receiver {
 public:
  explicit Receiver(std::uint8_t window = 4, std::size_t max_packet_bytes = 4096,
                    canopen::NodeId node = 3)
      : rx(node, PdopSpec{max_packet_bytes, 200ms, window}) {}

  bool feed(const Frame& frame) {
    acks.clear();
    packets.clear();
    return rx.on_frame(frame, now, acks, packets);
  }
  // Feeds a whole sequence, keeping every acknowledgement and packet.
  void feed_all(const std::vector<Frame>& frames) {
    std::vector<Frame> all_acks;
    std::vector<RpdopReceiver::Packet> all_packets;
    for (const Frame& f : frames) {
      ASSERT_TRUE(feed(f)) << can::to_string(f);
      all_acks.insert(all_acks.end(), acks.begin(), acks.end());
      for (auto& p : packets) all_packets.push_back(std::move(p));
    }
    acks = std::move(all_acks);
    packets = std::move(all_packets);
  }

  RpdopReceiver rx;
  RpdopReceiver::TimePoint now = RpdopReceiver::TimePoint{} + 1h;
  std::vector<Frame> acks;
  std::vector<RpdopReceiver::Packet> packets;
};

TEST(RpdopReceiver, WorkedExampleSeventeenBytesToNode3WithWindowTwo) {
  Receiver r(/*window=*/2);
  const Bytes packet = counting(17);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, packet);
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[0].id, 0x223u);
  EXPECT_EQ(frames[1].id, 0x263u);
  EXPECT_EQ(frames[2], Frame::standard(0x203, {0x10}));

  ASSERT_TRUE(r.feed(frames[0]));
  EXPECT_TRUE(r.acks.empty());
  ASSERT_TRUE(r.feed(frames[1]));
  EXPECT_EQ(r.acks, (std::vector<Frame>{Frame::standard(0x683, {0x01, 0x00, 0x02, 0x00, 0x02})}));
  ASSERT_TRUE(r.feed(frames[2]));
  EXPECT_EQ(r.acks, (std::vector<Frame>{Frame::standard(0x683, {0x01, 0x01, 0x03, 0x00, 0x02})}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].rpdo, 1u);
  EXPECT_EQ(r.packets[0].bytes, packet);
  EXPECT_EQ(r.rx.counters().packets, 1u);
}

TEST(RpdopReceiver, HappyPathAcksEveryWindowWithFullCredit) {
  Receiver r(/*window=*/4);
  const Bytes packet = counting(100);  // 13 fragments
  r.feed_all(pdop::fragment(pdop::rpdo_base(3), 3, packet));
  EXPECT_EQ(r.acks, (std::vector<Frame>{
                        ack_frame(3, 3, AckStatus::in_progress, 4, 4),
                        ack_frame(3, 3, AckStatus::in_progress, 8, 4),
                        ack_frame(3, 3, AckStatus::in_progress, 12, 4),
                        ack_frame(3, 3, AckStatus::complete, 13, 4),
                    }));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].rpdo, 3u);
  EXPECT_EQ(r.packets[0].bytes, packet);
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());
}

TEST(RpdopReceiver, LastFragmentGetsOnlyTheCompleteAckEvenAtAWindowBoundary) {
  Receiver r(/*window=*/2);
  r.feed_all(pdop::fragment(pdop::rpdo_base(1), 3, counting(32)));  // 4 fragments
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 2, 2),
                                        ack_frame(3, 1, AckStatus::complete, 4, 2)}));
}

TEST(RpdopReceiver, WindowOfOneAcksEveryFragment) {
  Receiver r(/*window=*/1);
  r.feed_all(pdop::fragment(pdop::rpdo_base(2), 3, counting(20)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::in_progress, 1, 1),
                                        ack_frame(3, 2, AckStatus::in_progress, 2, 1),
                                        ack_frame(3, 2, AckStatus::complete, 3, 1)}));
}

TEST(RpdopReceiver, OneFramePacketIsCompleteAndAcknowledged) {
  Receiver r;
  ASSERT_TRUE(r.feed(Frame::standard(0x403, {0xDE, 0xAD})));  // RPDO3, t = c = 0
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 3, AckStatus::complete, 1, 4)}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].rpdo, 3u);
  EXPECT_EQ(r.packets[0].bytes, (Bytes{0xDE, 0xAD}));
  // And another right after it: every packet starts afresh.
  ASSERT_TRUE(r.feed(Frame::standard(0x403, {1, 2, 3, 4, 5, 6, 7, 8})));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 3, AckStatus::complete, 1, 4)}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.rx.counters().packets, 2u);
}

// docs/pdop.md section 6, third example.
TEST(RpdopReceiver, ToggleErrorAbortsAndResynchronisesOnTheSenderAbort) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(40));  // 5 fragments
  ASSERT_TRUE(r.feed(frames[0]));
  ASSERT_TRUE(r.feed(frames[0]));  // duplicated: t = 0 again where t = 1 is expected
  EXPECT_EQ(r.acks, (std::vector<Frame>{Frame::standard(0x683, {0x01, 0x80, 0x01, 0x00, 0x04})}));
  EXPECT_EQ(r.rx.counters().toggle_errors, 1u);

  // The sender's window was already on the bus ahead of the (lower priority) ack. These strays
  // are dropped silently; fragment 2 (t = 0) must not start a packet that the next one could
  // continue.
  for (std::size_t k = 1; k <= 3; ++k) {
    ASSERT_TRUE(r.feed(frames[k]));
    EXPECT_TRUE(r.acks.empty()) << k;
    EXPECT_TRUE(r.packets.empty()) << k;
  }
  EXPECT_EQ(r.rx.counters().dropped_fragments, 3u);
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());

  ASSERT_TRUE(r.feed(Frame::standard(0x203, {})));  // the master's abort
  EXPECT_EQ(r.acks, (std::vector<Frame>{Frame::standard(0x683, {0x01, 0x85, 0x01, 0x00, 0x04})}));

  const Bytes packet = counting(12, 0x80);
  r.feed_all(pdop::fragment(pdop::rpdo_base(1), 3, packet));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, packet);
  EXPECT_EQ(r.acks.back(), ack_frame(3, 1, AckStatus::complete, 2, 4));
}

TEST(RpdopReceiver, StrayFinalFragmentAlsoEndsTheResynchronisation) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(24));  // 3 fragments
  ASSERT_TRUE(r.feed(frames[1]));  // the first fragment was lost: t = 1 while idle
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::toggle_error, 0, 4)}));
  ASSERT_TRUE(r.feed(frames[2]));  // c = 0: end of the broken packet
  EXPECT_TRUE(r.acks.empty());
  EXPECT_TRUE(r.packets.empty());

  ASSERT_TRUE(r.feed(pdop::ack_request(3)));  // closed now: the request gets its abort status
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::toggle_error, 0, 4)}));

  r.feed_all(pdop::fragment(pdop::rpdo_base(1), 3, counting(24)));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, counting(24));
}

TEST(RpdopReceiver, ToggleErrorOnAFinalFragmentLeavesTheReceiverReadyAtOnce) {
  Receiver r(/*window=*/4);
  ASSERT_TRUE(r.feed(fragment_frame(0x200, 3, false, true, counting(8))));
  ASSERT_TRUE(r.feed(fragment_frame(0x200, 3, false, false, counting(3))));  // t = 1 expected
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::toggle_error, 1, 4)}));
  EXPECT_TRUE(r.packets.empty());

  ASSERT_TRUE(r.feed(fragment_frame(0x200, 3, false, false, counting(3))));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::complete, 1, 4)}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, counting(3));
}

TEST(RpdopReceiver, OversizeAbortsWithStatus81) {
  Receiver r(/*window=*/4, /*max_packet_bytes=*/12);
  const auto frames = pdop::fragment(pdop::rpdo_base(2), 3, counting(24));
  ASSERT_TRUE(r.feed(frames[0]));
  ASSERT_TRUE(r.feed(frames[1]));  // 16 > 12
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::oversize, 1, 4)}));
  EXPECT_EQ(r.rx.counters().oversize, 1u);
  ASSERT_TRUE(r.feed(frames[2]));
  EXPECT_TRUE(r.acks.empty());
  EXPECT_TRUE(r.packets.empty());

  // Exactly max_packet_bytes is fine.
  const Bytes largest = counting(12);
  r.feed_all(pdop::fragment(pdop::rpdo_base(2), 3, largest));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, largest);
}

TEST(RpdopReceiver, OneFramePacketOverTheLimitIsOversize) {
  Receiver r(/*window=*/4, /*max_packet_bytes=*/4);
  ASSERT_TRUE(r.feed(Frame::standard(0x203, {1, 2, 3, 4, 5})));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::oversize, 0, 4)}));
  ASSERT_TRUE(r.feed(Frame::standard(0x203, {1, 2, 3, 4})));  // c = 0 closed it: ready at once
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::complete, 1, 4)}));
}

TEST(RpdopReceiver, ShortNonFinalFragmentAbortsWithStatus84) {
  Receiver r(/*window=*/4);
  ASSERT_TRUE(r.feed(fragment_frame(0x300, 3, false, true, counting(8))));
  ASSERT_TRUE(r.feed(fragment_frame(0x300, 3, true, true, counting(7))));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::short_fragment, 1, 4)}));
  EXPECT_EQ(r.rx.counters().short_fragments, 1u);

  // A first fragment too, and a zero-length frame with c = 1 (not an abort: that has c = 0).
  Receiver first(/*window=*/4);
  ASSERT_TRUE(first.feed(fragment_frame(0x300, 3, false, true, counting(1))));
  EXPECT_EQ(first.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::short_fragment, 0, 4)}));
  Receiver empty(/*window=*/4);
  ASSERT_TRUE(empty.feed(fragment_frame(0x300, 3, false, true, {})));
  EXPECT_EQ(empty.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::short_fragment, 0, 4)}));
}

TEST(RpdopReceiver, SenderAbortDiscardsThePartialPacket) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(4), 3, counting(40));
  for (std::size_t k = 0; k < 3; ++k) ASSERT_TRUE(r.feed(frames[k]));
  // t does not matter on an abort.
  ASSERT_TRUE(r.feed(fragment_frame(0x500, 3, true, false, {})));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 4, AckStatus::sender_abort, 3, 4)}));
  EXPECT_TRUE(r.packets.empty());
  EXPECT_EQ(r.rx.counters().sender_aborts, 1u);
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());

  // Confirmed even with nothing open, and the next packet starts at once.
  ASSERT_TRUE(r.feed(pdop::abort_frame(0x500, 3)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 4, AckStatus::sender_abort, 0, 4)}));
  r.feed_all(frames);
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, counting(40));
}

TEST(RpdopReceiver, FragmentTimeoutDiscardsAndTheRequestLearns83) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(40));
  ASSERT_TRUE(r.feed(frames[0]));
  r.now += 50ms;
  ASSERT_TRUE(r.feed(frames[1]));
  EXPECT_EQ(r.rx.next_deadline(), r.now + 200ms);  // counted from the last fragment

  const auto deadline = r.rx.next_deadline();
  r.rx.poll(deadline - 1ns);
  EXPECT_EQ(r.rx.counters().timeouts, 0u);
  r.rx.poll(deadline);  // silent: the node only answers when asked
  EXPECT_EQ(r.rx.counters().timeouts, 1u);
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());

  r.now = deadline + 10ms;
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::timeout, 2, 4)}));

  // A late fragment of the discarded packet is dropped; the sender's abort closes it.
  ASSERT_TRUE(r.feed(frames[2]));
  EXPECT_TRUE(r.acks.empty());
  ASSERT_TRUE(r.feed(pdop::abort_frame(0x200, 3)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::sender_abort, 2, 4)}));
  r.feed_all(frames);
  ASSERT_EQ(r.packets.size(), 1u);
}

TEST(RpdopReceiver, LateFragmentMeetsTheTimeoutWithoutAPoll) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(40));
  ASSERT_TRUE(r.feed(frames[0]));
  r.now += 200ms;  // exactly the timeout: too late
  ASSERT_TRUE(r.feed(frames[1]));
  EXPECT_TRUE(r.acks.empty());
  EXPECT_EQ(r.rx.counters().timeouts, 1u);
  EXPECT_EQ(r.rx.counters().dropped_fragments, 1u);
  EXPECT_EQ(r.rx.counters().toggle_errors, 0u);
}

TEST(RpdopReceiver, RequestMidPacketLetsTheSenderGoBackToReceived) {
  Receiver r(/*window=*/4);
  const Bytes packet = counting(40, 0x20);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, packet);  // 5 fragments
  // Fragments 0..3 are the first window; fragment 3 is lost on the way.
  for (std::size_t k = 0; k < 3; ++k) ASSERT_TRUE(r.feed(frames[k]));
  EXPECT_TRUE(r.acks.empty());

  r.now += 100ms;  // the sender's ack_timeout
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 3, 4)}));
  EXPECT_EQ(r.rx.counters().ack_requests, 1u);

  // Go-back-N from `received` = 3: fragment 3 carries t = 1, which the node expects.
  ASSERT_TRUE(r.feed(frames[3]));
  EXPECT_TRUE(r.acks.empty());
  ASSERT_TRUE(r.feed(frames[4]));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::complete, 5, 4)}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, packet);
}

TEST(RpdopReceiver, WindowCountsFromTheAnswerToARequest) {
  Receiver r(/*window=*/2);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(56));  // 7 fragments
  r.feed_all({frames[0], frames[1], frames[2]});
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 2, 2)}));
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));  // fragment 3 was lost
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 3, 2)}));
  // The answer granted fragments 3 and 4; the node acknowledges when they are used up.
  r.feed_all({frames[3], frames[4], frames[5], frames[6]});
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 5, 2),
                                        ack_frame(3, 1, AckStatus::complete, 7, 2)}));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, counting(56));
}

TEST(RpdopReceiver, RequestAnswersLastFinishedOrNothing) {
  Receiver r;
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));
  EXPECT_TRUE(r.acks.empty());  // nothing ever received

  r.feed_all(pdop::fragment(pdop::rpdo_base(2), 3, counting(10)));
  r.feed_all(pdop::fragment(pdop::rpdo_base(4), 3, counting(3)));
  // Any DLC asks.
  for (const std::uint8_t dlc : {0, 5, 8}) {
    Frame request = pdop::ack_request(3);
    request.len = dlc;
    ASSERT_TRUE(r.feed(request));
    EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 4, AckStatus::complete, 1, 4)}));
  }
  EXPECT_EQ(r.rx.counters().ack_requests, 4u);
}

TEST(RpdopReceiver, InterleavedPacketsOnRpdo1AndRpdo2) {
  Receiver r(/*window=*/2);
  const Bytes one = counting(24, 0x10);
  const Bytes two = counting(33, 0x90);
  const auto a = pdop::fragment(pdop::rpdo_base(1), 3, one);  // 3 fragments
  const auto b = pdop::fragment(pdop::rpdo_base(2), 3, two);  // 5 fragments
  r.feed_all({b[0], a[0], b[1], a[1], b[2]});
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 2, AckStatus::in_progress, 2, 2),
                                        ack_frame(3, 1, AckStatus::in_progress, 2, 2)}));

  ASSERT_TRUE(r.feed(pdop::ack_request(3)));  // every open packet, in RPDO order
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 2, 2),
                                        ack_frame(3, 2, AckStatus::in_progress, 3, 2)}));

  r.feed_all({a[2], b[3], b[4]});
  ASSERT_EQ(r.packets.size(), 2u);
  EXPECT_EQ(r.packets[0].rpdo, 1u);
  EXPECT_EQ(r.packets[0].bytes, one);
  EXPECT_EQ(r.packets[1].rpdo, 2u);
  EXPECT_EQ(r.packets[1].bytes, two);
}

TEST(RpdopReceiver, AbortedPacketStaysInTheAnswerUntilClosed) {
  Receiver r(/*window=*/4);
  const auto a = pdop::fragment(pdop::rpdo_base(1), 3, counting(40));
  const auto b = pdop::fragment(pdop::rpdo_base(2), 3, counting(40));
  r.feed_all({a[0], b[0], b[0]});  // RPDO2: toggle error
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(3, 1, AckStatus::in_progress, 1, 4),
                                        ack_frame(3, 2, AckStatus::toggle_error, 1, 4)}));
}

TEST(RpdopReceiver, IgnoresFramesThatAreNotItsRpdopTraffic) {
  Receiver r;
  const std::vector<Frame> foreign = {
      Frame::standard(0x204, {1, 2, 3}),                      // RPDO1 of node 4
      Frame::standard(0x224, {1, 2, 3, 4, 5, 6, 7, 8}),       // fragment for node 4
      Frame::standard(0x183, {1, 2}),                         // node 3's own TPDO1
      Frame::standard(0x683, {1, 1, 1, 0, 4}),                // an acknowledgement
      Frame::standard(0x603, {0x40, 0x00, 0x10, 0x00}),       // SDO request
      Frame::make(0x203, can::FrameFlags::remote, {}),        // remote frames are no fragments
      Frame::make(0x203, can::FrameFlags::extended, {1, 2}),  // 29-bit identifier
      Frame::make(0x684, can::FrameFlags::remote, {}),        // another node's request
      Frame::standard(0x000, {0x01, 0x03}),                   // NMT start node 3
  };
  for (const Frame& f : foreign) {
    EXPECT_FALSE(r.feed(f)) << can::to_string(f);
    EXPECT_TRUE(r.acks.empty());
    EXPECT_TRUE(r.packets.empty());
  }
  EXPECT_EQ(r.rx.counters().ack_requests, 0u);
  EXPECT_EQ(r.rx.counters().packets, 0u);
}

TEST(RpdopReceiver, ResetDiscardsSilentlyAndForgets) {
  Receiver r(/*window=*/4);
  const auto frames = pdop::fragment(pdop::rpdo_base(1), 3, counting(40));
  r.feed_all({frames[0], frames[1]});
  r.rx.reset();
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());
  ASSERT_TRUE(r.feed(pdop::ack_request(3)));
  EXPECT_TRUE(r.acks.empty());
  r.feed_all(frames);  // fragment 0 starts afresh
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, counting(40));
}

TEST(RpdopReceiver, NewNodeIdMovesTheIdentifiers) {
  Receiver r(/*window=*/4);
  ASSERT_TRUE(r.feed(pdop::fragment(pdop::rpdo_base(1), 3, counting(16))[0]));
  EXPECT_FALSE(r.rx.set_node_id(0));
  EXPECT_FALSE(r.rx.set_node_id(32));
  EXPECT_EQ(r.rx.node_id(), 3);
  ASSERT_TRUE(r.rx.set_node_id(31));
  EXPECT_EQ(r.rx.next_deadline(), RpdopReceiver::TimePoint::max());  // reset
  EXPECT_FALSE(r.feed(Frame::standard(0x203, {1})));
  ASSERT_TRUE(r.feed(Frame::standard(0x21F, {1})));
  EXPECT_EQ(r.acks, (std::vector<Frame>{ack_frame(31, 1, AckStatus::complete, 1, 4)}));
  EXPECT_EQ(r.acks[0].id, 0x69Fu);
}

TEST(RpdopReceiver, RejectsBadNodeOrSpec) {
  const PdopSpec good;
  EXPECT_NO_THROW(RpdopReceiver(1, good));
  EXPECT_NO_THROW(RpdopReceiver(31, good));
  EXPECT_THROW(RpdopReceiver(0, good), std::invalid_argument);
  EXPECT_THROW(RpdopReceiver(32, good), std::invalid_argument);
  EXPECT_THROW(RpdopReceiver(1, (PdopSpec{0, 200ms, 4})), std::invalid_argument);
  EXPECT_THROW(RpdopReceiver(1, (PdopSpec{pdop::kMaxPacketBytes + 1, 200ms, 4})),
               std::invalid_argument);
  EXPECT_NO_THROW(RpdopReceiver(1, (PdopSpec{pdop::kMaxPacketBytes, 10s, 255})));
  EXPECT_THROW(RpdopReceiver(1, (PdopSpec{4096, 0ms, 4})), std::invalid_argument);
  EXPECT_THROW(RpdopReceiver(1, (PdopSpec{4096, 10001ms, 4})), std::invalid_argument);
  EXPECT_THROW(RpdopReceiver(1, (PdopSpec{4096, 200ms, 0})), std::invalid_argument);
}

TEST(RpdopReceiver, LargestPacketEveryRpdo) {
  Receiver r(/*window=*/255, pdop::kMaxPacketBytes);
  Bytes largest(pdop::kMaxPacketBytes);
  for (std::size_t i = 0; i < largest.size(); ++i) largest[i] = static_cast<std::uint8_t>(i * 7);
  r.feed_all(pdop::fragment(pdop::rpdo_base(4), 3, largest));
  ASSERT_EQ(r.packets.size(), 1u);
  EXPECT_EQ(r.packets[0].bytes, largest);
  // 65,535 = 257 x 255: 256 window acks, then "complete" in place of the 257th.
  EXPECT_EQ(r.acks.size(), 257u);
  EXPECT_EQ(r.acks.back(), ack_frame(3, 4, AckStatus::complete, 65535, 255));

  for (unsigned n = 1; n <= 4; ++n) {
    r.feed_all(pdop::fragment(pdop::rpdo_base(n), 3, counting(77, static_cast<std::uint8_t>(n))));
    ASSERT_EQ(r.packets.size(), 1u);
    EXPECT_EQ(r.packets[0].rpdo, n);
    EXPECT_EQ(r.packets[0].bytes, counting(77, static_cast<std::uint8_t>(n)));
  }
}

}  // namespace
}  // namespace canbridge::sim
