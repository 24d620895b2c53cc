// FrameOutbox against a fake session sink: arbitration order, each sender's order, every lane's
// bound and overflow rule, conflation, backpressure, the write budget, batch boundaries, and the
// wire cost per frame.
#include "bridge/frame_outbox.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "tests/support/fake_payload_sink.hpp"

namespace canbridge::bridge {
namespace {

using test::FakeSink;
using test::kEnvelopeBytes;

struct DecodedBatch {
  std::uint32_t module_id;
  bool reliable;
  std::vector<can::Frame> frames;
};

// Parses every recorded payload as the receiving role does (v1::Payload -> decode_frame_batch).
std::vector<DecodedBatch> decode(const FakeSink& sink) {
  std::vector<DecodedBatch> out;
  for (const auto& s : sink.sent) {
    v1::Payload payload;
    EXPECT_TRUE(payload.ParseFromString(s.bytes));
    EXPECT_TRUE(payload.has_frames());
    DecodedBatch b{payload.frames().module_id(), s.reliable, {}};
    EXPECT_EQ(decode_frame_batch(payload.frames(), b.frames), BatchError::none);
    out.push_back(std::move(b));
  }
  return out;
}

std::vector<can::Frame> all_frames(const std::vector<DecodedBatch>& batches) {
  std::vector<can::Frame> out;
  for (const auto& b : batches) out.insert(out.end(), b.frames.begin(), b.frames.end());
  return out;
}

std::vector<std::uint32_t> ids(const std::vector<can::Frame>& frames) {
  std::vector<std::uint32_t> out;
  for (const auto& f : frames) out.push_back(f.id);
  return out;
}

// Produces until the outbox is empty, one fresh write per call; false if it stops making progress.
bool drain(FrameOutbox& outbox, FakeSink& sink) {
  for (int writes = 0; !outbox.empty(); ++writes) {
    if (writes > 100000) return false;
    sink.next_write();
    const std::size_t before = outbox.size();
    outbox.produce(sink);
    if (outbox.size() == before) return false;
  }
  return true;
}

// The delivery options the roles pass: a module that conflates its PDOs, one that keeps them
// all, and a node whose PDO Packets cross as frames.
constexpr DeliveryOptions kConflate{.conflate_pdos = true};
constexpr DeliveryOptions kKeep{.conflate_pdos = false};
constexpr DeliveryOptions kFragments{.conflate_pdos = true, .pdop_fragments = true};

// When the frames of a test were read off their bus: one instant, as one batch read gives them.
const FrameOutbox::Clock::time_point kNow =
    FrameOutbox::Clock::time_point{} + std::chrono::hours(1);

// conflate_after 0: the link counts as behind whenever a value is still queued, so frames pushed
// at one instant conflate (the rule before conflate_after existed).
FrameOutbox::Options always_conflating() {
  FrameOutbox::Options options;
  options.conflate_after = std::chrono::milliseconds(0);
  return options;
}

can::Frame extended(std::uint32_t id, std::initializer_list<std::uint8_t> bytes) {
  return can::Frame::make(id, can::FrameFlags::extended, bytes);
}

TEST(FrameOutbox, FramesLeaveInCanArbitrationOrder) {
  FrameOutbox outbox({});
  const std::uint32_t kModule = 1;
  // Pushed in reverse of the expected order (but for the master's own two frames, which keep
  // theirs), and the extended frame before its standard twin. Every frame from another sender.
  const can::Frame heartbeat = can::Frame::standard(0x701, {0x05});
  const can::Frame sdo = can::Frame::standard(0x582, {0x43, 0x00, 0x10});
  const can::Frame pdo_next = can::Frame::standard(0x182, {0x22});
  const can::Frame nmt = can::Frame::standard(0x000, {0x01, 0x00});
  const can::Frame ext_same_base = extended((0x181u << 18) | 0x5, {0xEE});
  const can::Frame pdo = can::Frame::standard(0x181, {0x11});
  const can::Frame emcy = can::Frame::standard(0x083, {0x00, 0x10});
  const can::Frame sync = can::Frame::standard(0x080, {});
  for (const auto& f : {heartbeat, sdo, pdo_next, nmt, ext_same_base, pdo, emcy, sync}) {
    ASSERT_TRUE(outbox.push(kModule, f, kConflate, kNow));
  }
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  const auto frames = all_frames(decode(sink));
  EXPECT_EQ(frames, (std::vector{nmt, sync, emcy, pdo, ext_same_base, pdo_next, sdo, heartbeat}));
  EXPECT_EQ(outbox.counters().frames_sent, 8u);
}

TEST(FrameOutbox, FramesOfOneCobIdStayInArrivalOrder) {
  FrameOutbox outbox({});
  for (std::uint8_t i = 0; i < 20; ++i) {
    ASSERT_TRUE(
        outbox.push(1, can::Frame::standard(0x585, {0x43, i}), kConflate, kNow));    // reliable
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x085, {i}), kConflate, kNow));  // reliable
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x185, {i}), kKeep, kNow));      // process
  }
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  std::vector<std::uint8_t> sdo, emcy, pdo;
  for (const auto& f : all_frames(decode(sink))) {
    if (f.id == 0x585) sdo.push_back(f.data[1]);
    if (f.id == 0x085) emcy.push_back(f.data[0]);
    if (f.id == 0x185) pdo.push_back(f.data[0]);
  }
  std::vector<std::uint8_t> expected(20);
  for (std::uint8_t i = 0; i < 20; ++i) expected[i] = i;
  EXPECT_EQ(sdo, expected);
  EXPECT_EQ(emcy, expected);
  EXPECT_EQ(pdo, expected);
}

TEST(FrameOutbox, PacketFragmentsLeaveInBusOrderNotArbitrationOrder) {
  // A 40-byte PDO Packet of node 1 on TPDO1: 1A1, 1E1, 1A1, 1E1, 181 (docs/pdop.md section 2).
  std::vector<can::Frame> fragments;
  for (std::uint32_t k = 0; k < 5; ++k) {
    const std::uint32_t id = 0x181 | (k % 2 ? 0x40u : 0u) | (k < 4 ? 0x20u : 0u);
    fragments.push_back(
        can::Frame::standard(id, {static_cast<std::uint8_t>(k), 1, 2, 3, 4, 5, 6, 7}));
  }
  const can::Frame other = can::Frame::standard(0x182, {0x22});  // another node's PDO
  for (bool in_order : {false, true}) {
    FrameOutbox outbox(always_conflating());
    for (const auto& f : fragments) {
      ASSERT_TRUE(outbox.push(1, f, in_order ? kFragments : kConflate, kNow));
    }
    ASSERT_TRUE(outbox.push(1, other, kConflate, kNow));  // node 2 is no pdop node
    FakeSink sink;
    ASSERT_TRUE(drain(outbox, sink));
    const auto frames = all_frames(decode(sink));
    ASSERT_EQ(frames.size(), in_order ? 6u : 4u);
    if (in_order) {
      // In bus order and before 0x182, as the packet's first fragment (0x1A1 -> 0x181) ranks.
      auto expected = fragments;
      expected.push_back(other);
      EXPECT_EQ(frames, expected);
    } else {
      // Plain arbitration order: the last fragment (0x181) first, fragments 0 and 2 conflated.
      EXPECT_EQ(frames.front(), fragments.back());
    }
  }
}

TEST(FrameOutbox, ConflationKeepsTheLatestProcessValueOnlyWhenAllowed) {
  FrameOutbox conflating(always_conflating());
  for (std::uint8_t v = 1; v <= 5; ++v) {
    ASSERT_TRUE(conflating.push(1, can::Frame::standard(0x181, {v}), kConflate, kNow));
  }
  // Same COB-ID on another module is another signal: not conflated with module 1's.
  ASSERT_TRUE(conflating.push(2, can::Frame::standard(0x181, {9}), kConflate, kNow));
  EXPECT_EQ(conflating.size(), 2u);
  EXPECT_EQ(conflating.counters().conflated, 4u);
  FakeSink sink;
  ASSERT_TRUE(drain(conflating, sink));
  const auto batches = decode(sink);
  ASSERT_EQ(batches.size(), 2u);
  EXPECT_EQ(batches[0].module_id, 1u);
  EXPECT_EQ(batches[0].frames, (std::vector{can::Frame::standard(0x181, {5})}));
  EXPECT_EQ(batches[1].module_id, 2u);

  FrameOutbox keeping(always_conflating());
  for (std::uint8_t v = 1; v <= 5; ++v) {
    ASSERT_TRUE(keeping.push(1, can::Frame::standard(0x181, {v}), kKeep, kNow));
  }
  EXPECT_EQ(keeping.counters().conflated, 0u);
  FakeSink all;
  ASSERT_TRUE(drain(keeping, all));
  std::vector<can::Frame> expected;
  for (std::uint8_t v = 1; v <= 5; ++v) expected.push_back(can::Frame::standard(0x181, {v}));
  EXPECT_EQ(all_frames(decode(all)), expected);
}

TEST(FrameOutbox, ReliableFramesAreNeverConflated) {
  FrameOutbox outbox({});
  const std::vector<can::Frame> frames = {can::Frame::standard(0x585, {0x60, 1}),
                                          can::Frame::standard(0x585, {0x60, 2}),
                                          can::Frame::standard(0x085, {0x00, 0x10}),
                                          can::Frame::standard(0x085, {0x00, 0x20}),
                                          can::Frame::standard(0x705, {0x00}),  // boot-ups
                                          can::Frame::standard(0x705, {0x00}),
                                          extended(0x1234567, {1}),
                                          extended(0x1234567, {2})};
  for (const auto& f : frames) ASSERT_TRUE(outbox.push(1, f, kConflate, kNow));
  EXPECT_EQ(outbox.size(), frames.size());
  EXPECT_EQ(outbox.counters().conflated, 0u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  const auto batches = decode(sink);
  EXPECT_EQ(all_frames(batches).size(), frames.size());
  for (const auto& b : batches) EXPECT_TRUE(b.reliable);
}

TEST(FrameOutbox, HeartbeatStatesAreConflatedAndUnreliableWhileBootUpsAreNot) {
  // A cut queues heartbeats; only the newest per node may reach the surface afterwards, and never
  // as a replay (reliable payloads are resent). Boot-ups are events: every one is delivered.
  FrameOutbox outbox({});
  for (std::uint8_t state : {0x7F, 0x05, 0x05, 0x04}) {
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x705, {state}), kKeep, kNow));
  }
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x706, {0x05}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x707, {0x00}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x707, {0x00}), kKeep, kNow));
  EXPECT_EQ(outbox.counters().conflated, 3u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  const auto batches = decode(sink);
  std::vector<can::Frame> states, boot_ups;
  for (const auto& b : batches) {
    for (const auto& f : b.frames) (b.reliable ? boot_ups : states).push_back(f);
  }
  EXPECT_EQ(states, (std::vector{can::Frame::standard(0x705, {0x04}),
                                 can::Frame::standard(0x706, {0x05})}));
  EXPECT_EQ(boot_ups, (std::vector{can::Frame::standard(0x707, {0x00}),
                                   can::Frame::standard(0x707, {0x00})}));
}

TEST(FrameOutbox, WithdrawnSdoRequestsAreNeverSentAndLaterOnesAre) {
  // The surface aborted these requests when the link dropped: they must not reach a node later.
  FrameOutbox outbox({});
  const can::Frame old_request = can::Frame::standard(0x625, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  const can::Frame response = can::Frame::standard(0x5A5, {0x43, 0x00, 0x10, 0x00, 1, 0, 0, 0});
  const can::Frame nmt = can::Frame::standard(0x000, {0x01, 0x25});
  // Another withdrawn request behind the master's NMT (not at the head of the master's FIFO).
  const can::Frame old_request_2 = can::Frame::standard(0x626, {0x40, 0x00, 0x10, 0x00, 0, 0, 0});
  ASSERT_TRUE(outbox.push(1, old_request, kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, nmt, kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, response, kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, old_request_2, kConflate, kNow));
  std::vector<can::Frame> seen;  // each withdrawn request, for its sender's accounting
  outbox.withdraw_queued_sdo_requests([&](const can::Frame& f) { seen.push_back(f); });
  EXPECT_EQ(seen, (std::vector{old_request, old_request_2}));
  EXPECT_EQ(outbox.counters().sdo_requests_withdrawn, 2u);
  EXPECT_EQ(outbox.size(), 2u);  // gone at once: the NMT no longer waits behind a request
  const can::Frame new_request = can::Frame::standard(0x625, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0});
  ASSERT_TRUE(outbox.push(1, new_request, kConflate, kNow));
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)), (std::vector{nmt, response, new_request}));
  EXPECT_EQ(outbox.counters().sdo_requests_withdrawn, 2u);
}

// Nothing reliable that waited longer than reliable_max_age leaves; the owner sees each frame so
// that the surface can answer an SDO request with an abort. A batch is as old as its oldest frame.
TEST(FrameOutbox, ReliableFramesOlderThanTheMaxAgeAreDroppedAndReported) {
  using namespace std::chrono_literals;
  FrameOutbox::Options options;
  options.reliable_max_age = 4000ms;
  FrameOutbox outbox(options);
  std::vector<std::pair<can::Frame, FrameOutbox::Discard>> reported;
  outbox.on_discard([&](std::uint32_t, const can::Frame& f, FrameOutbox::Discard why) {
    reported.emplace_back(f, why);
  });
  FakeSink sink;
  const auto t0 = sink.now_;
  const can::Frame stop = can::Frame::standard(0x000, {0x02, 0x25});
  const can::Frame request = can::Frame::standard(0x625, {0x23, 0x17, 0x10, 0x00, 0xE8, 3, 0, 0});
  const can::Frame pdo = can::Frame::standard(0x225, {1, 2});
  const can::Frame fresh = can::Frame::standard(0x0A5, {1, 2});
  ASSERT_TRUE(outbox.push(1, stop, kConflate, t0));
  ASSERT_TRUE(outbox.push(1, request, kConflate, t0 + 1ms));
  ASSERT_TRUE(outbox.push(1, pdo, kConflate, t0));  // process data: latest value, not aged
  ASSERT_TRUE(outbox.push(1, fresh, kConflate, t0 + 3000ms));
  sink.now_ = t0 + 4002ms;  // the request is 4001 ms old, the NMT stop 4002 ms
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)), (std::vector{fresh, pdo}));
  ASSERT_EQ(reported.size(), 2u);
  EXPECT_EQ(reported[0].first, stop);
  EXPECT_EQ(reported[1].first, request);
  EXPECT_EQ(reported[1].second, FrameOutbox::Discard::too_old);
  EXPECT_EQ(outbox.counters().reliable_too_old, 2u);
  ASSERT_EQ(sink.borns.size(), 1u);
  EXPECT_EQ(sink.borns[0], t0 + 3000ms);
}

// A new peer process: nothing queued for the old one is sent to it.
TEST(FrameOutbox, DiscardQueuedDropsEverythingAndReportsTheReliableFrames) {
  FrameOutbox outbox({});
  std::vector<can::Frame> reported;
  outbox.on_discard([&](std::uint32_t, const can::Frame& f, FrameOutbox::Discard why) {
    EXPECT_EQ(why, FrameOutbox::Discard::peer_restart);
    reported.push_back(f);
  });
  const can::Frame reset = can::Frame::standard(0x000, {0x81, 0x25});
  const can::Frame pdo = can::Frame::standard(0x225, {1, 2});
  ASSERT_TRUE(outbox.push(1, reset, kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, pdo, kConflate, kNow));
  outbox.discard_queued();
  EXPECT_TRUE(outbox.empty());
  EXPECT_EQ(reported, (std::vector{reset}));
  EXPECT_EQ(outbox.counters().discarded_peer_restart, 2u);
  FakeSink sink;
  EXPECT_TRUE(drain(outbox, sink));
  EXPECT_TRUE(sink.sent.empty());
}

TEST(FrameOutbox, SdoRequestsAreWithdrawnFromAProducedPayload) {
  FrameOutbox outbox({});
  const can::Frame request = can::Frame::standard(0x625, {0x23, 0x00, 0x18, 0x01, 1, 2, 3, 4});
  const can::Frame nmt = can::Frame::standard(0x000, {0x82, 0x25});
  const can::Frame emcy = can::Frame::standard(0x0A5, {1, 2});
  for (const auto& f : {nmt, emcy, request})
    ASSERT_TRUE(outbox.push(kAnyModule, f, kConflate, kNow));
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  ASSERT_EQ(sink.sent.size(), 1u);
  std::string payload = sink.sent[0].bytes;
  std::vector<can::Frame> seen;
  EXPECT_EQ(withdraw_sdo_requests(payload, [&](const can::Frame& f) { seen.push_back(f); }), 1u);
  EXPECT_EQ(seen, std::vector{request});
  FakeSink edited;
  edited.sent.push_back({payload, true, 0});
  const auto batches = decode(edited);
  ASSERT_EQ(batches.size(), 1u);
  EXPECT_EQ(batches[0].module_id, kAnyModule);
  EXPECT_EQ(batches[0].frames, (std::vector{nmt, emcy}));
  // Nothing to withdraw: untouched; garbage: left alone.
  std::string unchanged = payload;
  EXPECT_EQ(withdraw_sdo_requests(unchanged), 0u);
  EXPECT_EQ(unchanged, payload);
  std::string garbage = "\xff\x01";
  EXPECT_EQ(withdraw_sdo_requests(garbage), 0u);
  EXPECT_EQ(garbage, "\xff\x01");
}

// A request whose answer is overdue on a live link: only that node's requests go, from the queue
// and from what was sent unacknowledged; the other nodes' requests and every other frame stay.
TEST(FrameOutbox, TheSdoRequestsOfOneNodeAreWithdrawnAndNoOther) {
  FrameOutbox outbox({});
  const can::Frame to_37 = can::Frame::standard(0x625, {0x40, 0x00, 0x18, 0x01, 0, 0, 0, 0});
  const can::Frame to_38 = can::Frame::standard(0x626, {0x40, 0x00, 0x18, 0x01, 0, 0, 0, 0});
  const can::Frame nmt = can::Frame::standard(0x000, {0x82, 0x25});
  for (const auto& f : {to_37, nmt, to_38})
    ASSERT_TRUE(outbox.push(kAnyModule, f, kConflate, kNow));
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  std::string payload = sink.sent.at(0).bytes;
  std::vector<can::Frame> seen;
  EXPECT_EQ(withdraw_sdo_requests(
                payload, [&](const can::Frame& f) { seen.push_back(f); }, 0x25),
            1u);
  EXPECT_EQ(seen, std::vector{to_37});
  FakeSink edited;
  edited.sent.push_back({payload, true, 0});
  EXPECT_EQ(decode(edited).at(0).frames, (std::vector{nmt, to_38}));

  for (const auto& f : {to_37, to_38}) ASSERT_TRUE(outbox.push(kAnyModule, f, kConflate, kNow));
  seen.clear();
  outbox.withdraw_queued_sdo_requests([&](const can::Frame& f) { seen.push_back(f); }, 0x26);
  EXPECT_EQ(seen, std::vector{to_38});
  EXPECT_EQ(outbox.counters().sdo_requests_withdrawn, 1u);
  FakeSink rest;
  ASSERT_TRUE(drain(outbox, rest));
  EXPECT_EQ(all_frames(decode(rest)), std::vector{to_37});
}

TEST(FrameOutbox, AFullReliableQueueRefusesAndCounts) {
  FrameOutbox::Options options;
  options.max_reliable_frames = 4;
  options.max_process_frames = 2;
  FrameOutbox outbox(options);
  for (std::uint8_t i = 0; i < 4; ++i) {
    EXPECT_TRUE(outbox.push(1, can::Frame::standard(0x585, {i}), kConflate, kNow));
  }
  EXPECT_FALSE(outbox.push(1, can::Frame::standard(0x585, {4}), kConflate, kNow));
  EXPECT_EQ(outbox.counters().reliable_refused, 1u);
  // Process data has its own bound, so a full reliable lane does not block it (and vice versa);
  // a full process lane drops its oldest frame for the newest.
  EXPECT_TRUE(outbox.push(1, can::Frame::standard(0x181, {1}), kKeep, kNow));
  EXPECT_TRUE(outbox.push(1, can::Frame::standard(0x182, {1}), kKeep, kNow));
  EXPECT_TRUE(outbox.push(1, can::Frame::standard(0x183, {1}), kKeep, kNow));
  const OutboxCounters c = outbox.counters();
  EXPECT_EQ(c.process_dropped, 1u);
  EXPECT_EQ(c.reliable_refused, 1u);
  EXPECT_EQ(c.lanes[static_cast<std::size_t>(DeliveryClass::reliable)].refused, 1u);
  EXPECT_EQ(c.lanes[static_cast<std::size_t>(DeliveryClass::process_data)].dropped_oldest, 1u);
  EXPECT_EQ(c.queued, 7u);
  EXPECT_EQ(outbox.size(), 6u);

  // Room again once the queue drains.
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  std::vector<std::uint32_t> process_ids;
  for (const auto& f : all_frames(decode(sink))) {
    if (f.id != 0x585) process_ids.push_back(f.id);
  }
  EXPECT_EQ(process_ids, (std::vector<std::uint32_t>{0x182, 0x183}));
  EXPECT_TRUE(outbox.push(1, can::Frame::standard(0x585, {5}), kConflate, kNow));
}

TEST(FrameOutbox, ReliableFramesWaitWhileTheResendBufferIsFull) {
  FrameOutbox outbox({});
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x085, {0x00, 0x10}), kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x585, {0x60}), kConflate, kNow));
  FakeSink sink;
  sink.reliable_room_ = false;
  for (int write = 0; write < 3; ++write) {
    sink.next_write();
    outbox.produce(sink);
  }
  EXPECT_TRUE(sink.sent.empty());
  EXPECT_EQ(sink.reliable_calls_while_full_, 0u);
  EXPECT_EQ(outbox.size(), 2u);  // held, not popped and lost

  sink.reliable_room_ = true;
  sink.next_write();
  outbox.produce(sink);
  EXPECT_TRUE(outbox.empty());
  const auto frames = all_frames(decode(sink));
  EXPECT_EQ(frames, (std::vector{can::Frame::standard(0x085, {0x00, 0x10}),
                                 can::Frame::standard(0x585, {0x60})}));
}

TEST(FrameOutbox, NoPayloadExceedsTheRoomOfItsWrite) {
  // Full PDOs of one module and small extended (reliable, escaped) frames of another.
  auto fill = [](FrameOutbox& outbox) {
    for (int i = 0; i < 300; ++i) {
      const auto v = static_cast<std::uint8_t>(i);
      const auto pdo = static_cast<std::uint32_t>(0x181 + i % 50);
      if (!outbox.push(1, can::Frame::standard(pdo, {v, v, v, v, v, v, v, v}), kKeep, kNow))
        return false;
      if (!outbox.push(2, extended(0x100000u + static_cast<std::uint32_t>(i), {v}), kConflate,
                       kNow)) {
        return false;
      }
    }
    return true;
  };
  for (std::size_t room :
       {std::size_t{64}, std::size_t{100}, std::size_t{250}, std::size_t{5000}}) {
    FrameOutbox outbox({});
    ASSERT_TRUE(fill(outbox));
    FakeSink sink(room);
    ASSERT_TRUE(drain(outbox, sink)) << "room " << room;
    for (const auto& s : sink.sent) {
      // The payload and its envelope both fit in what the write had left.
      EXPECT_LE(s.bytes.size() + kEnvelopeBytes, s.room_before) << "room " << room;
    }
    EXPECT_EQ(all_frames(decode(sink)).size(), 600u) << "room " << room;
  }
  // A write too small for one frame is left alone rather than overfilled.
  FrameOutbox outbox({});
  ASSERT_TRUE(fill(outbox));
  FakeSink tiny(20);
  outbox.produce(tiny);
  EXPECT_TRUE(tiny.sent.empty());
  EXPECT_EQ(outbox.size(), 600u);
}

TEST(FrameOutbox, BatchesSplitByModuleAndClass) {
  FrameOutbox outbox({});
  // Arbitration order interleaves modules and classes: 0x181(m1) 0x182(m1) | 0x183(m2) |
  // 0x184(m1) | 0x585(m1, reliable) 0x586(m1, reliable) | 0x705(m2, reliable).
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x181, {1}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x182, {2}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(2, can::Frame::standard(0x183, {3}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x184, {4}), kKeep, kNow));
  // SDO and boot-up are reliable whatever the conflate flag says.
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x585, {5}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x586, {6}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(2, can::Frame::standard(0x705, {0x00}), kKeep, kNow));
  FakeSink sink;
  sink.next_write();
  outbox.produce(sink);  // everything fits one write
  EXPECT_TRUE(outbox.empty());
  const auto batches = decode(sink);
  ASSERT_EQ(batches.size(), 5u);
  const std::vector<std::uint32_t> modules = {1, 2, 1, 1, 2};
  const std::vector<bool> reliable = {false, false, false, true, true};
  const std::vector<std::vector<std::uint32_t>> expected_ids = {
      {0x181, 0x182}, {0x183}, {0x184}, {0x585, 0x586}, {0x705}};
  for (std::size_t i = 0; i < batches.size(); ++i) {
    EXPECT_EQ(batches[i].module_id, modules[i]) << "batch " << i;
    EXPECT_EQ(batches[i].reliable, reliable[i]) << "batch " << i;
    EXPECT_EQ(ids(batches[i].frames), expected_ids[i]) << "batch " << i;
  }
  EXPECT_EQ(outbox.counters().batches_sent, 5u);
  EXPECT_EQ(outbox.counters().frames_sent, 7u);
}

TEST(FrameOutbox, StandardFramesCostAboutTenBytesEach) {
  constexpr std::size_t kFrames = 10000;
  FrameOutbox outbox({});
  for (std::size_t i = 0; i < kFrames; ++i) {
    const auto v = static_cast<std::uint8_t>(i);
    const auto id = static_cast<std::uint32_t>(0x181 + i % 0x3FF);  // 0x181..0x57F: PDOs
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(id, {v, 1, 2, 3, 4, 5, 6, 7}), kKeep, kNow));
  }
  FakeSink sink(16 * 1024);
  ASSERT_TRUE(drain(outbox, sink));
  std::size_t payload_bytes = 0;
  for (const auto& s : sink.sent) payload_bytes += s.bytes.size();
  const auto frames = all_frames(decode(sink));
  ASSERT_EQ(frames.size(), kFrames);
  const double per_frame = static_cast<double>(payload_bytes) / kFrames;
  const double with_envelopes =
      static_cast<double>(payload_bytes + sink.sent.size() * kEnvelopeBytes) / kFrames;
  std::printf(
      "FrameOutbox: %zu frames in %zu payloads, %.3f payload bytes/frame (%.3f with "
      "envelopes)\n",
      kFrames, sink.sent.size(), per_frame, with_envelopes);
  ::testing::Test::RecordProperty("payload_bytes_per_frame", std::to_string(per_frame));
  EXPECT_LE(per_frame, 10.5);
  EXPECT_LE(with_envelopes, 10.5);
}

// ---------------------------------------------------------------------------------------------
// Each sender's order (issue 14: a boot-up and the EMCY right after it arrived swapped).

std::vector<std::string> names(const std::vector<can::Frame>& frames,
                               const std::vector<std::pair<can::Frame, std::string>>& known) {
  std::vector<std::string> out;
  for (const auto& f : frames) {
    std::string name = "?";
    for (const auto& [frame, n] : known) {
      if (frame == f) name = n;
    }
    out.push_back(name);
  }
  return out;
}

TEST(FrameOutbox, OneNodesReliableFramesKeepItsOrderWhileNodesFollowArbitration) {
  // Node 5 boots and reports an EMCY right after; node 3's frames interleave. All cross in one
  // batch. Node 3 may overtake node 5 (its head 0x083 wins arbitration over 0x705), but node 5's
  // EMCY (0x085) must not overtake node 5's boot-up.
  const can::Frame boot_up_5 = can::Frame::standard(0x705, {0x00});
  const can::Frame emcy_3 = can::Frame::standard(0x083, {0x00, 0x10, 0x01});
  const can::Frame emcy_5 = can::Frame::standard(0x085, {0x00, 0x50, 0x01});
  const can::Frame sdo_3 = can::Frame::standard(0x583, {0x60, 0x17, 0x10});
  const can::Frame emcy_5_reset = can::Frame::standard(0x085, {0x00, 0x00, 0x00});
  const std::vector<std::pair<can::Frame, std::string>> known = {{boot_up_5, "boot-up 5"},
                                                                 {emcy_3, "emcy 3"},
                                                                 {emcy_5, "emcy 5"},
                                                                 {sdo_3, "sdo 3"},
                                                                 {emcy_5_reset, "emcy-reset 5"}};
  FrameOutbox outbox({});
  for (const auto& f : {boot_up_5, emcy_3, emcy_5, sdo_3, emcy_5_reset}) {
    ASSERT_TRUE(outbox.push(1, f, kConflate, kNow));
  }
  FakeSink sink;
  sink.next_write();
  outbox.produce(sink);
  ASSERT_TRUE(outbox.empty());
  ASSERT_EQ(sink.sent.size(), 1u);  // one batch
  EXPECT_EQ(names(all_frames(decode(sink)), known),
            (std::vector<std::string>{"emcy 3", "sdo 3", "boot-up 5", "emcy 5", "emcy-reset 5"}));
}

TEST(FrameOutbox, NodesOfDifferentModulesAreDifferentSenders) {
  // Node 5 of module 2 is another device than node 5 of module 1: it is not held behind it.
  FrameOutbox outbox({});
  const can::Frame boot_up_5 = can::Frame::standard(0x705, {0x00});
  const can::Frame emcy_5 = can::Frame::standard(0x085, {0x00, 0x50, 0x01});
  ASSERT_TRUE(outbox.push(1, boot_up_5, kConflate, kNow));
  ASSERT_TRUE(outbox.push(2, emcy_5, kConflate, kNow));
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  const auto batches = decode(sink);
  ASSERT_EQ(batches.size(), 2u);
  EXPECT_EQ(batches[0].module_id, 2u);
  EXPECT_EQ(batches[1].module_id, 1u);
}

TEST(FrameOutbox, TheMastersFramesKeepTheMastersOrder) {
  // A master writes 1017h of node 5 and then starts all nodes: the NMT (0x000, the bus's most
  // urgent identifier) must not reach the far bus before the SDO request sent ahead of it. Other
  // senders still overtake by arbitration: node 1's EMCY leaves before the master's request.
  const can::Frame request = can::Frame::standard(0x605, {0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03});
  const can::Frame nmt_start = can::Frame::standard(0x000, {0x01, 0x00});
  const can::Frame sync = can::Frame::standard(0x080, {});  // process data: not the master's FIFO
  const can::Frame emcy_1 = can::Frame::standard(0x081, {0x00, 0x10});
  const can::Frame lss = can::Frame::standard(0x7E5, {0x04, 0x01});
  const std::vector<std::pair<can::Frame, std::string>> known = {
      {request, "request"}, {nmt_start, "nmt"}, {sync, "sync"}, {emcy_1, "emcy 1"}, {lss, "lss"}};
  FrameOutbox outbox({});
  for (const auto& f : {request, nmt_start, sync, emcy_1, lss}) {
    ASSERT_TRUE(outbox.push(kAnyModule, f, kConflate, kNow));
  }
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(names(all_frames(decode(sink)), known),
            (std::vector<std::string>{"sync", "emcy 1", "request", "nmt", "lss"}));
}

// ---------------------------------------------------------------------------------------------
// Process data conflates only while the link is behind (Options::conflate_after, 200 ms).

using std::chrono::milliseconds;

can::Frame counter_pdo(std::uint32_t id, std::uint32_t n) {
  return can::Frame::standard(
      id, {static_cast<std::uint8_t>(n), static_cast<std::uint8_t>(n >> 8), 0, 0, 0, 0, 0, 0});
}

TEST(FrameOutbox, AYoungBurstOfOneCobIdCrossesWholeInOrderInLargeBatches) {
  // One TPDO at 20,000 frames/s for 100 ms: its oldest frame never waits 200 ms, so nothing is
  // conflated, and the frames queued together leave together.
  FrameOutbox outbox({});
  constexpr std::uint32_t kFrames = 2000;
  std::vector<can::Frame> sent;
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    sent.push_back(counter_pdo(0x181, i));
    ASSERT_TRUE(outbox.push(1, sent.back(), kConflate, kNow + std::chrono::microseconds(50 * i)));
  }
  EXPECT_EQ(outbox.size(), kFrames);
  EXPECT_EQ(outbox.counters().conflated, 0u);
  FakeSink sink;
  sink.now_ = kNow + milliseconds(100);
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)), sent);
  EXPECT_LE(outbox.counters().batches_sent, kFrames / 300);  // about 400 frames per 4 KiB batch
}

TEST(FrameOutbox, OnceTheOldestFrameOfACobIdWaitedPastTheLimitNewValuesConflate) {
  FrameOutbox outbox({});
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 1), kConflate, kNow));
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 2), kConflate, kNow + milliseconds(100)));
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 3), kConflate, kNow + milliseconds(200)));  // at
  EXPECT_EQ(outbox.counters().conflated, 0u);
  // Past the limit: the frames queued in time stay; the newer ones share one entry after them.
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 4), kConflate, kNow + milliseconds(201)));
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 5), kConflate, kNow + milliseconds(230)));
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 6), kConflate, kNow + milliseconds(260)));
  EXPECT_EQ(outbox.counters().conflated, 2u);
  EXPECT_EQ(outbox.size(), 4u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)), (std::vector{counter_pdo(0x181, 1), counter_pdo(0x181, 2),
                                                   counter_pdo(0x181, 3), counter_pdo(0x181, 6)}));
  // The link caught up: the COB-ID's frames are all kept again.
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 7), kConflate, kNow + milliseconds(300)));
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 8), kConflate, kNow + milliseconds(301)));
  EXPECT_EQ(outbox.size(), 2u);
  EXPECT_EQ(outbox.counters().conflated, 2u);
}

TEST(FrameOutbox, OnlyTheCobIdThatIsBehindConflates) {
  FrameOutbox outbox({});
  const auto late = kNow + milliseconds(250);
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, 1), kConflate, kNow));  // waits 250+ ms below
  ASSERT_TRUE(outbox.push(1, counter_pdo(0x182, 1), kConflate, late));
  ASSERT_TRUE(outbox.push(2, counter_pdo(0x181, 1), kConflate, late));  // module 2: its own
  ASSERT_TRUE(outbox.push(3, counter_pdo(0x181, 1), kKeep, kNow));      // keeps whatever the age
  for (std::uint32_t v = 2; v <= 4; ++v) {
    const auto at = late + milliseconds(v);
    ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, v), kConflate, at));
    ASSERT_TRUE(outbox.push(1, counter_pdo(0x182, v), kConflate, at));
    ASSERT_TRUE(outbox.push(2, counter_pdo(0x181, v), kConflate, at));
    ASSERT_TRUE(outbox.push(3, counter_pdo(0x181, v), kKeep, at));
  }
  EXPECT_EQ(outbox.counters().conflated, 2u);  // module 1's 0x181: values 3 and 4 into 2
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::vector<std::uint8_t>> values;
  for (const auto& b : decode(sink)) {
    for (const auto& f : b.frames) values[{b.module_id, f.id}].push_back(f.data[0]);
  }
  EXPECT_EQ(values[std::pair(1u, 0x181u)], (std::vector<std::uint8_t>{1, 4}));
  EXPECT_EQ(values[std::pair(1u, 0x182u)], (std::vector<std::uint8_t>{1, 2, 3, 4}));
  EXPECT_EQ(values[std::pair(2u, 0x181u)], (std::vector<std::uint8_t>{1, 2, 3, 4}));
  EXPECT_EQ(values[std::pair(3u, 0x181u)], (std::vector<std::uint8_t>{1, 2, 3, 4}));
}

TEST(FrameOutbox, ConflateAfterZeroConflatesEveryQueuedValue) {
  FrameOutbox outbox(always_conflating());
  for (std::uint32_t v = 1; v <= 5; ++v) {
    ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, v), kConflate, kNow));
  }
  EXPECT_EQ(outbox.size(), 1u);
  EXPECT_EQ(outbox.counters().conflated, 4u);
}

TEST(FrameOutbox, AFullProcessLaneDropsTheOldestOfAYoungBurst) {
  FrameOutbox::Options options;
  options.max_process_frames = 3;
  FrameOutbox outbox(options);
  for (std::uint32_t v = 1; v <= 5; ++v) {
    ASSERT_TRUE(outbox.push(1, counter_pdo(0x181, v), kConflate, kNow + milliseconds(v)));
  }
  const auto lane = outbox.counters().lanes[static_cast<std::size_t>(DeliveryClass::process_data)];
  EXPECT_EQ(lane.conflated, 0u);
  EXPECT_EQ(lane.dropped_oldest, 2u);
  EXPECT_EQ(outbox.counters().process_dropped, 2u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)),
            (std::vector{counter_pdo(0x181, 3), counter_pdo(0x181, 4), counter_pdo(0x181, 5)}));
}

// ---------------------------------------------------------------------------------------------
// Every lane's bound and overflow rule (bridge/delivery_lanes.hpp).

TEST(FrameOutbox, AFullLatestValueLaneDropsTheOldestValue) {
  FrameOutbox::Options options;
  options.max_latest_values = 2;
  FrameOutbox outbox(options);
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x701, {0x05}), kKeep, kNow));
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x702, {0x05}), kKeep, kNow));
  ASSERT_TRUE(
      outbox.push(1, can::Frame::standard(0x701, {0x04}), kKeep, kNow));  // replaces, in place
  ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x703, {0x7F}), kKeep, kNow));  // drops node 1's
  const auto lane = outbox.counters().lanes[static_cast<std::size_t>(DeliveryClass::latest_value)];
  EXPECT_EQ(lane.conflated, 1u);
  EXPECT_EQ(lane.dropped_oldest, 1u);
  EXPECT_EQ(lane.refused, 0u);
  EXPECT_EQ(outbox.counters().process_dropped, 1u);
  EXPECT_EQ(outbox.lane_size(DeliveryClass::latest_value), 2u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  const auto batches = decode(sink);
  for (const auto& b : batches) EXPECT_FALSE(b.reliable);  // never resent
  EXPECT_EQ(all_frames(batches), (std::vector{can::Frame::standard(0x702, {0x05}),
                                              can::Frame::standard(0x703, {0x7F})}));
}

TEST(FrameOutbox, AFullProcessLaneDropsTheOldestWhetherOrNotItConflates) {
  for (const DeliveryOptions& options : {kKeep, kConflate}) {
    FrameOutbox::Options bounds = always_conflating();
    bounds.max_process_frames = 3;
    FrameOutbox outbox(bounds);
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x181, {1}), options, kNow));
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x182, {1}), options, kNow));
    ASSERT_TRUE(
        outbox.push(1, can::Frame::standard(0x181, {2}), options, kNow));  // conflated or kept
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x183, {1}), options, kNow));
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x184, {1}), options, kNow));
    const auto lane =
        outbox.counters().lanes[static_cast<std::size_t>(DeliveryClass::process_data)];
    FakeSink sink;
    ASSERT_TRUE(drain(outbox, sink));
    const auto frames = all_frames(decode(sink));
    if (options.conflate_pdos) {
      EXPECT_EQ(lane.conflated, 1u);
      EXPECT_EQ(lane.dropped_oldest, 1u);  // 0x181 (value 2) was the oldest entry
      EXPECT_EQ(ids(frames), (std::vector<std::uint32_t>{0x182, 0x183, 0x184}));
    } else {
      EXPECT_EQ(lane.conflated, 0u);
      EXPECT_EQ(lane.dropped_oldest, 2u);  // 0x181 (value 1), then 0x182
      EXPECT_EQ(frames,
                (std::vector{can::Frame::standard(0x181, {2}), can::Frame::standard(0x183, {1}),
                             can::Frame::standard(0x184, {1})}));
    }
  }
}

TEST(FrameOutbox, AFullFragmentLaneRefusesNewFragments) {
  FrameOutbox::Options options;
  options.max_fragment_frames = 2;
  FrameOutbox outbox(options);
  const can::Frame f0 = can::Frame::standard(0x1A1, {0, 1, 2, 3, 4, 5, 6, 7});
  const can::Frame f1 = can::Frame::standard(0x1E1, {1, 1, 2, 3, 4, 5, 6, 7});
  const can::Frame f2 = can::Frame::standard(0x1A1, {2, 1, 2, 3, 4, 5, 6, 7});
  EXPECT_TRUE(outbox.push(1, f0, kFragments, kNow));
  EXPECT_TRUE(outbox.push(1, f1, kFragments, kNow));
  EXPECT_FALSE(
      outbox.push(1, f2, kFragments, kNow));  // an older fragment stays: its packet is intact
  const auto c = outbox.counters();
  EXPECT_EQ(c.lanes[static_cast<std::size_t>(DeliveryClass::ordered_fragment)].refused, 1u);
  EXPECT_EQ(c.lanes[static_cast<std::size_t>(DeliveryClass::ordered_fragment)].conflated, 0u);
  EXPECT_EQ(c.process_dropped, 1u);
  EXPECT_EQ(c.reliable_refused, 0u);
  FakeSink sink;
  ASSERT_TRUE(drain(outbox, sink));
  EXPECT_EQ(all_frames(decode(sink)), (std::vector{f0, f1}));
}

TEST(FrameOutbox, LaneCountersAddUpAcrossOutboxesAndShowInOneSummary) {
  FrameOutbox a(always_conflating());
  FrameOutbox b(always_conflating());
  ASSERT_TRUE(a.push(1, can::Frame::standard(0x181, {1}), kConflate, kNow));
  ASSERT_TRUE(a.push(1, can::Frame::standard(0x181, {2}), kConflate, kNow));
  ASSERT_TRUE(b.push(1, can::Frame::standard(0x585, {1}), kConflate, kNow));
  OutboxCounters sum;
  sum += a.counters();
  sum += b.counters();
  EXPECT_EQ(sum.queued, 2u);
  EXPECT_EQ(sum.conflated, 1u);
  EXPECT_EQ(sum.lanes[static_cast<std::size_t>(DeliveryClass::reliable)].queued, 1u);
  EXPECT_EQ(sum.lanes[static_cast<std::size_t>(DeliveryClass::process_data)].queued, 1u);
  EXPECT_EQ(sum.lanes[static_cast<std::size_t>(DeliveryClass::process_data)].conflated, 1u);
  EXPECT_EQ(lanes_summary(sum),
            "lane reliable queued 1 conflated 0 dropped-oldest 0 refused 0, "
            "lane latest-value queued 0 conflated 0 dropped-oldest 0 refused 0, "
            "lane process queued 1 conflated 1 dropped-oldest 0 refused 0, "
            "lane fragment queued 0 conflated 0 dropped-oldest 0 refused 0");
}

}  // namespace
}  // namespace canbridge::bridge

namespace canbridge::bridge {
namespace {

// Process data is never resent, so the receiver can only count what the line lost if each
// unreliable batch says how many process frames were sent up to it; reliable batches say nothing.
TEST(FrameOutbox, UnreliableBatchesCarryTheRunningCountOfProcessFramesSent) {
  FrameOutbox::Options options;
  options.max_batch_bytes = 200;  // several batches
  FrameOutbox outbox(options);
  FakeSink sink;
  for (std::uint8_t i = 0; i < 60; ++i) {
    // Process data, not conflated (every frame counts), with some SDO responses among it.
    ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x181 + (i % 20), {i, i, i, i}),
                            DeliveryOptions{}, kNow));
    if (i % 10 == 0) {
      ASSERT_TRUE(outbox.push(1, can::Frame::standard(0x585, {0x43, i}), DeliveryOptions{}, kNow));
    }
  }
  ASSERT_TRUE(drain(outbox, sink));
  std::uint64_t sent = 0;
  std::size_t unreliable_batches = 0;
  for (const auto& s : sink.sent) {
    v1::Payload payload;
    ASSERT_TRUE(payload.ParseFromString(s.bytes));
    std::vector<can::Frame> frames;
    ASSERT_EQ(decode_frame_batch(payload.frames(), frames), BatchError::none);
    if (s.reliable) {
      EXPECT_EQ(payload.frames().process_frames_sent(), 0u);
      continue;
    }
    ++unreliable_batches;
    sent += frames.size();
    EXPECT_EQ(payload.frames().process_frames_sent(), sent);
  }
  EXPECT_EQ(sent, 60u);
  EXPECT_GT(unreliable_batches, 2u);
}

}  // namespace
}  // namespace canbridge::bridge
