// The gateway's RPDOP sender (docs/pdop.md section 4): explicit exchanges with hand-made
// acknowledgements and injected times (credit pacing, completion, each receiver abort, requests,
// retries and giving up, the abort handshake, cancel, concurrency, edge node ids, refusals,
// foreign frames, options), then a property test against the simulated node's receiver
// (sim/rpdop_receiver) over a lossy, duplicating, delaying in-memory bus.
#include "routing/pdop_segmenter.hpp"

#include <gtest/gtest-spi.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <deque>
#include <iostream>
#include <map>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <tuple>
#include <utility>
#include <vector>

#include "can/frame.hpp"
#include "canopen/pdop.hpp"
#include "sim/rpdop_receiver.hpp"
#include "tests/bridge/rpdop_test_helpers.hpp"

namespace canbridge::bridge {
namespace {

using namespace rpdop_test;

namespace pdop = canopen::pdop;
using namespace std::chrono_literals;
using can::Frame;
using pdop::Ack;
using pdop::AckStatus;
using TimePoint = PdopSegmenter::TimePoint;
using Duration = PdopSegmenter::Duration;

Frames slice(const Frames& frames, std::size_t from, std::size_t to) {
  return Frames(frames.begin() + static_cast<std::ptrdiff_t>(from),
                frames.begin() + static_cast<std::ptrdiff_t>(to));
}
Frames concat(Frames a, const Frames& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}
// One segmenter at an injected time; every call starts with an empty output.
struct Rig {
  explicit Rig(PdopSegmenterOptions options = {}) : seg(options) {}

  void submit(NodeId node, unsigned rpdo, Bytes bytes, std::uint64_t id) {
    clear();
    seg.submit(node, rpdo, std::move(bytes), id, now, out);
  }
  bool frame(const Frame& f) {
    clear();
    return seg.on_frame(f, now, out);
  }
  bool ack(NodeId node, std::uint8_t rpdo, AckStatus status, std::uint16_t received,
           std::uint8_t credit = 4) {
    return frame(pdop::encode_ack(node, Ack{rpdo, status, received, credit}));
  }
  bool raw_ack(NodeId node, std::uint8_t rpdo, std::uint8_t status, std::uint16_t received,
               std::uint8_t credit = 4) {
    return ack(node, rpdo, static_cast<AckStatus>(status), received, credit);
  }
  // Moves the clock to t0 + `since_t0` and ticks.
  void at(Duration since_t0) {
    now = t0 + since_t0;
    clear();
    seg.tick(now, out);
  }
  void clear() {
    out.frames.clear();
    out.outcomes.clear();
  }
  const PdopOutcome& only_outcome() const {
    static const PdopOutcome none{};
    EXPECT_EQ(out.outcomes.size(), 1u);
    return out.outcomes.empty() ? none : out.outcomes.front();
  }

  PdopSegmenter seg;
  TimePoint now = t0;
  PdopSegmenter::Output out;
};

// ---- Pacing and completion ----------------------------------------------------------------------

TEST(PdopSegmenter, WorkedExampleSeventeenBytesToNode3WithWindowTwo) {
  Rig r({.window = 2});
  const Bytes packet = counting(17);
  r.submit(3, 1, packet, 7);
  EXPECT_EQ(r.out.frames, (Frames{Frame::standard(0x223, {0, 1, 2, 3, 4, 5, 6, 7}),
                                  Frame::standard(0x263, {8, 9, 10, 11, 12, 13, 14, 15})}));
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_EQ(r.seg.active_request(3, 1), 7u);

  r.now += 3ms;
  ASSERT_TRUE(r.frame(Frame::standard(0x683, {0x01, 0x00, 0x02, 0x00, 0x02})));
  EXPECT_EQ(r.out.frames, (Frames{Frame::standard(0x203, {0x10})}));

  r.now += 2ms;
  ASSERT_TRUE(r.frame(Frame::standard(0x683, {0x01, 0x01, 0x03, 0x00, 0x02})));
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.only_outcome(), (PdopOutcome{.request_id = 7,
                                           .node = 3,
                                           .rpdo = 1,
                                           .result = PdopResult::complete,
                                           .status = AckStatus::complete,
                                           .fragments = 3,
                                           .fragments_sent = 3,
                                           .retransmissions = 0,
                                           .ack_requests = 0,
                                           .elapsed = 5ms}));
  EXPECT_EQ(r.seg.active_request(3, 1), std::nullopt);
  EXPECT_EQ(r.seg.next_deadline(), std::nullopt);
  EXPECT_EQ(r.seg.held_bytes(), 0u);
  EXPECT_EQ(r.seg.counters().complete, 1u);
  EXPECT_EQ(r.seg.counters().fragments_sent, 3u);
}

TEST(PdopSegmenter, CreditPacesTheFragmentsAndMayShrink) {
  Rig r({.window = 4});
  const Bytes packet = counting(100);  // 13 fragments
  const Frames all = fragments(5, 2, packet);
  r.submit(5, 2, packet, 1);
  EXPECT_EQ(r.out.frames, slice(all, 0, 4));  // the first window

  ASSERT_TRUE(r.ack(5, 2, AckStatus::in_progress, 4, 2));  // 4 + 2: up to fragment 5
  EXPECT_EQ(r.out.frames, slice(all, 4, 6));
  ASSERT_TRUE(r.ack(5, 2, AckStatus::in_progress, 5, 1));  // 5 + 1 = 6: nothing more
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(5, 2, AckStatus::in_progress, 6, 0));  // credit 0: wait
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(5, 2, AckStatus::in_progress, 6, 3));
  EXPECT_EQ(r.out.frames, slice(all, 6, 9));
  // A node with a bigger FIFO: credit beyond the packet's end sends only what is left.
  ASSERT_TRUE(r.ack(5, 2, AckStatus::in_progress, 7, 255));
  EXPECT_EQ(r.out.frames, slice(all, 9, 13));
  ASSERT_TRUE(r.ack(5, 2, AckStatus::complete, 13, 4));
  EXPECT_EQ(r.only_outcome().result, PdopResult::complete);
  EXPECT_EQ(r.only_outcome().fragments_sent, 13u);
}

TEST(PdopSegmenter, CreditShrinkHoldsFragmentsAlreadyAllowedByAnOlderAcknowledgement) {
  Rig r({.window = 2});
  const Bytes packet = counting(80);  // 10 fragments
  const Frames all = fragments(4, 1, packet);
  r.submit(4, 1, packet, 1);
  EXPECT_EQ(r.out.frames, slice(all, 0, 2));
  ASSERT_TRUE(r.ack(4, 1, AckStatus::in_progress, 1, 8));  // up to 8
  EXPECT_EQ(r.out.frames, slice(all, 2, 9));
  // The node's FIFO filled: its latest word is received 2 + credit 0; fragment 9 waits.
  ASSERT_TRUE(r.ack(4, 1, AckStatus::in_progress, 2, 0));
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(4, 1, AckStatus::in_progress, 9, 1));
  EXPECT_EQ(r.out.frames, slice(all, 9, 10));
}

// Every fragment sent is below the latest acknowledgement's received + credit (or the first
// window), whatever credits the node gives, and the packet still completes.
TEST(PdopSegmenter, NeverMoreInFlightThanTheCreditAllows) {
  std::mt19937 rng(11);
  for (int round = 0; round < 200; ++round) {
    const auto window = static_cast<std::uint8_t>(1 + rng() % 8);
    Rig r({.window = window});
    const Bytes packet = counting(1 + rng() % 400, static_cast<std::uint8_t>(round));
    const Frames all = fragments(9, 3, packet);
    r.submit(9, 3, packet, 1);
    std::uint32_t sent = 0;
    std::uint32_t limit = window;
    auto take = [&] {
      for (const Frame& f : r.out.frames) {
        ASSERT_LT(sent, all.size());
        ASSERT_EQ(f, all[sent]);
        ++sent;
        ASSERT_LE(sent, limit) << "fragment " << sent - 1 << " beyond the credit";
      }
    };
    take();
    std::uint32_t received = 0;
    while (received < all.size()) {
      // The node accepts some of what was sent and grants a random credit (0 included).
      received += static_cast<std::uint32_t>(rng() % (sent - received + 1));
      if (received == all.size()) break;
      const auto credit = static_cast<std::uint8_t>(rng() % 6);
      r.now += 1ms;
      ASSERT_TRUE(
          r.ack(9, 3, AckStatus::in_progress, static_cast<std::uint16_t>(received), credit));
      limit = received + credit;
      take();
      if (sent == received && credit == 0) {
        ASSERT_TRUE(r.ack(9, 3, AckStatus::in_progress, static_cast<std::uint16_t>(received), 1));
        limit = received + 1;
        take();
      }
    }
    ASSERT_EQ(sent, all.size());
    ASSERT_TRUE(r.ack(9, 3, AckStatus::complete, static_cast<std::uint16_t>(all.size())));
    ASSERT_EQ(r.only_outcome().result, PdopResult::complete) << "round " << round;
  }
}

TEST(PdopSegmenter, OneFramePacketIsAPlainPdoAndCompletesOnItsAcknowledgement) {
  Rig r;
  r.submit(3, 1, {0xAA, 0xBB}, 1);
  EXPECT_EQ(r.out.frames, (Frames{Frame::standard(0x203, {0xAA, 0xBB})}));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 1));
  EXPECT_EQ(r.only_outcome().result, PdopResult::complete);
  EXPECT_EQ(r.only_outcome().fragments, 1u);
}

TEST(PdopSegmenter, FramesAreTheCodecsFragmentsForEverySize) {
  for (std::size_t size = 1; size <= 70; ++size) {
    Rig r({.window = 255});
    const Bytes packet = counting(size, static_cast<std::uint8_t>(size));
    r.submit(17, 4, packet, size);
    EXPECT_EQ(r.out.frames, fragments(17, 4, packet)) << size;
  }
  Rig r({.max_packet_bytes = pdop::kMaxPacketBytes,
         .window = 255,
         .max_held_bytes = pdop::kMaxPacketBytes});
  Bytes largest(pdop::kMaxPacketBytes, 0x5A);
  r.submit(1, 1, largest, 1);
  EXPECT_EQ(r.out.frames, slice(fragments(1, 1, largest), 0, 255));
}

TEST(PdopSegmenter, CompleteIsCountedOnlyWithTheLastFragmentSentAndAllOfIt) {
  Rig r;
  const Bytes packet = counting(48);  // 6 fragments
  r.submit(3, 1, packet, 1);
  // status 1 before the last fragment went out: about an earlier packet (section 4.3).
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 4));
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4));
  EXPECT_EQ(r.out.frames, slice(fragments(3, 1, packet), 4, 6));
  // status 1 with another count: not this packet.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 5));
  EXPECT_TRUE(r.out.outcomes.empty());
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 6));
  EXPECT_EQ(r.only_outcome().result, PdopResult::complete);
  EXPECT_EQ(r.seg.counters().ignored_acks, 2u);
}

TEST(PdopSegmenter, QueuedPacketsOnOneRpdoGoOneAfterTheOther) {
  Rig r({.queue_per_rpdo = 2});
  r.submit(3, 1, counting(8), 1);
  EXPECT_EQ(r.out.frames.size(), 1u);
  r.submit(3, 1, counting(9, 50), 2);
  r.submit(3, 1, counting(3, 90), 3);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.seg.queued(3, 1), 2u);
  r.submit(3, 1, counting(3), 4);
  EXPECT_EQ(r.only_outcome().result, PdopResult::refused_busy);
  EXPECT_EQ(r.only_outcome().request_id, 4u);

  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 1));
  EXPECT_EQ(r.only_outcome().request_id, 1u);
  EXPECT_EQ(r.out.frames, fragments(3, 1, counting(9, 50)));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 2));
  EXPECT_EQ(r.only_outcome().request_id, 2u);
  EXPECT_EQ(r.out.frames, fragments(3, 1, counting(3, 90)));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 1));
  EXPECT_EQ(r.only_outcome().request_id, 3u);
  EXPECT_EQ(r.seg.held_bytes(), 0u);
  EXPECT_EQ(r.seg.next_deadline(), std::nullopt);
}

// ---- Receiver aborts and the abort handshake ----------------------------------------------------

class ReceiverAbort : public ::testing::TestWithParam<std::uint8_t> {};

TEST_P(ReceiverAbort, StopsReportsTheStatusAbortsAndWaitsForTheConfirmation) {
  const std::uint8_t status = GetParam();
  Rig r;
  const Bytes packet = counting(64);  // 8 fragments
  const Frames all = fragments(6, 2, packet);
  r.submit(6, 2, packet, 21);
  EXPECT_EQ(r.out.frames, slice(all, 0, 4));
  r.now += 4ms;
  ASSERT_TRUE(r.raw_ack(6, 2, status, 1));
  EXPECT_EQ(r.out.frames, (Frames{abort_of(6, 2)}));
  const PdopOutcome& o = r.only_outcome();
  EXPECT_EQ(o.result, PdopResult::receiver_abort);
  EXPECT_EQ(static_cast<std::uint8_t>(o.status), status);
  EXPECT_EQ(o.request_id, 21u);
  EXPECT_EQ(o.fragments, 8u);
  EXPECT_EQ(o.fragments_sent, 4u);
  EXPECT_EQ(o.elapsed, 4ms);
  EXPECT_EQ(r.seg.counters().receiver_aborts, 1u);
  EXPECT_EQ(r.seg.active_request(6, 2), std::nullopt);

  // Stray acknowledgements of the broken packet change nothing; the next packet waits for 0x85.
  ASSERT_TRUE(r.ack(6, 2, AckStatus::in_progress, 4));
  ASSERT_TRUE(r.raw_ack(6, 2, status, 1));
  EXPECT_TRUE(r.out.frames.empty());
  r.submit(6, 2, counting(10, 100), 22);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.outcomes.empty());
  ASSERT_TRUE(r.ack(6, 2, AckStatus::sender_abort, 0));
  EXPECT_EQ(r.out.frames, fragments(6, 2, counting(10, 100)));
  EXPECT_EQ(r.seg.active_request(6, 2), 22u);
}

std::string status_name(const ::testing::TestParamInfo<std::uint8_t>& param) {
  static const char* const kNames[] = {"toggle", "oversize", "out_of_memory", "timeout",
                                       "short_fragment"};
  const unsigned i = param.param - 0x80u;
  return i < 5 ? std::string(kNames[i]) : "undefined_" + std::to_string(param.param);
}

INSTANTIATE_TEST_SUITE_P(EachStatus, ReceiverAbort,
                         ::testing::Values(0x80, 0x81, 0x82, 0x83, 0x84, 0x86, 0xFF), status_name);

TEST(PdopSegmenter, ReceiverAbortOnTheLastFragmentAndOnAnAnswer) {
  Rig r;
  r.submit(3, 1, counting(24), 1);  // 3 fragments, all sent
  ASSERT_TRUE(r.ack(3, 1, AckStatus::toggle_error, 2));
  EXPECT_EQ(r.only_outcome().result, PdopResult::receiver_abort);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::sender_abort, 0));

  // The node timed out the packet: it only says so when asked (section 4.3).
  r.submit(3, 1, counting(24), 2);
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  r.now += 1ms;
  ASSERT_TRUE(r.ack(3, 1, AckStatus::timeout, 2));
  EXPECT_EQ(r.only_outcome().result, PdopResult::receiver_abort);
  EXPECT_EQ(r.only_outcome().status, AckStatus::timeout);
  EXPECT_EQ(r.only_outcome().ack_requests, 1u);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(3, 1)}));
}

TEST(PdopSegmenter, UnconfirmedAbortIsSentAgainThenTheNextPacketGoesAfterAnAbort) {
  Rig r({.retries = 2});
  r.submit(3, 1, counting(40), 1);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::short_fragment, 0));
  EXPECT_EQ(r.out.frames, (Frames{abort_of(3, 1)}));
  r.submit(3, 1, counting(5), 2);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.seg.next_deadline(), t0 + 100ms);
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(3, 1)}));
  r.at(200ms);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(3, 1)}));  // 3 = retries + 1 abort frames
  r.at(300ms);
  // Gave up waiting: the next packet goes, after an abort frame of its own.
  EXPECT_EQ(r.out.frames, concat(Frames{abort_of(3, 1)}, fragments(3, 1, counting(5))));
  EXPECT_EQ(r.seg.counters().resync_gave_up, 1u);
  EXPECT_EQ(r.seg.counters().abort_frames, 4u);
  // That late 0x85 is no news for the running packet.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::sender_abort, 0));
  EXPECT_TRUE(r.out.outcomes.empty());
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 1));
  EXPECT_EQ(r.only_outcome().request_id, 2u);
}

TEST(PdopSegmenter, SenderAbortConfirmationIsIgnoredWhileSending) {
  Rig r;
  r.submit(3, 1, counting(40), 1);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::sender_abort, 0));
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.seg.active_request(3, 1), 1u);
  EXPECT_EQ(r.seg.counters().ignored_acks, 1u);
}

// ---- Timeouts, requests, retries ----------------------------------------------------------------

TEST(PdopSegmenter, UnansweredRequestsThenTimeoutAndAbort) {
  Rig r;  // ack_timeout 100 ms, retries 3
  r.submit(7, 3, counting(40), 5);
  EXPECT_EQ(r.seg.next_deadline(), t0 + 100ms);
  r.at(100ms - 1ns);
  EXPECT_TRUE(r.out.frames.empty());
  for (int request = 1; request <= 3; ++request) {
    r.at(request * 100ms);
    const Frame remote = pdop::ack_request(7);
    EXPECT_EQ(r.out.frames, (Frames{remote})) << request;
    EXPECT_TRUE(r.out.frames.front().is_remote());
    EXPECT_EQ(r.out.frames.front().id, 0x687u);
    EXPECT_EQ(r.out.frames.front().len, 5u);
    EXPECT_EQ(r.seg.next_deadline(), t0 + (request + 1) * 100ms);
  }
  r.at(400ms);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(7, 3)}));
  const PdopOutcome& o = r.only_outcome();
  EXPECT_EQ(o.result, PdopResult::timeout);
  EXPECT_EQ(o.ack_requests, 3u);
  EXPECT_EQ(o.fragments_sent, 4u);
  EXPECT_EQ(o.elapsed, 400ms);
  EXPECT_EQ(r.seg.counters().timeouts, 1u);
  EXPECT_EQ(r.seg.counters().ack_requests, 3u);
}

TEST(PdopSegmenter, NoRetriesGivesUpAtTheFirstTimeout) {
  Rig r({.ack_timeout = 20ms, .retries = 0});
  r.submit(7, 3, counting(40), 5);
  r.at(20ms);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(7, 3)}));
  EXPECT_EQ(r.only_outcome().result, PdopResult::timeout);
  EXPECT_EQ(r.only_outcome().ack_requests, 0u);
}

TEST(PdopSegmenter, AnsweredRequestGoesBackToReceivedAndResetsTheRetries) {
  Rig r;
  const Bytes packet = counting(100);  // 13 fragments
  const Frames all = fragments(3, 1, packet);
  r.submit(3, 1, packet, 1);
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  r.now += 2ms;
  // The node holds fragments 0 and 1 (the acknowledgement of a lost window, say).
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 2, 4));
  EXPECT_EQ(r.out.frames, slice(all, 2, 6));
  // Not the first after the request: only the limit moves, never `next` back.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 2, 4));
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 6, 4));
  EXPECT_EQ(r.out.frames, slice(all, 6, 10));
  // Three more requests before giving up: the answer reset the count.
  for (int i = 1; i <= 3; ++i) {
    r.at(102ms + i * 100ms);
    EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)})) << i;
  }
  r.now += 1ms;
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 10, 4));  // answer: resume at 10
  EXPECT_EQ(r.out.frames, slice(all, 10, 13));
  r.now += 1ms;
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 13, 4));
  const PdopOutcome& o = r.only_outcome();
  EXPECT_EQ(o.result, PdopResult::complete);
  EXPECT_EQ(o.fragments_sent, 15u);
  EXPECT_EQ(o.retransmissions, 2u);  // fragments 2 and 3
  EXPECT_EQ(o.ack_requests, 4u);
}

TEST(PdopSegmenter, TheAnswersCreditBoundsWhatIsSentAgain) {
  Rig r({.window = 2});
  const Bytes packet = counting(96);  // 12 fragments
  const Frames all = fragments(3, 1, packet);
  r.submit(3, 1, packet, 1);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 1, 8));
  EXPECT_EQ(r.out.frames, slice(all, 2, 9));
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  // The node has 2 and room for 2 more: fragments 2 and 3 again, not up to the old limit 9.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 2, 2));
  EXPECT_EQ(r.out.frames, slice(all, 2, 4));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 2));
  EXPECT_EQ(r.out.frames, slice(all, 4, 6));
}

TEST(PdopSegmenter, LostCompleteAcknowledgementIsLearntFromTheAnswer) {
  Rig r;
  r.submit(3, 1, counting(24), 1);
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  r.now += 1ms;
  ASSERT_TRUE(r.ack(3, 1, AckStatus::complete, 3));
  EXPECT_EQ(r.only_outcome().result, PdopResult::complete);
  EXPECT_EQ(r.only_outcome().retransmissions, 0u);
}

TEST(PdopSegmenter, StaleAcknowledgementsAreIgnored) {
  Rig r;
  const Bytes packet = counting(100);
  r.submit(3, 1, packet, 1);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 4));
  EXPECT_EQ(r.out.frames.size(), 4u);
  // Below what the node already said, or above what was ever sent.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 3, 4));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 9, 4));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::toggle_error, 2, 4));
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.outcomes.empty());
  // Also when a request is out: a stale answer does not move the sender back.
  r.at(100ms);
  ASSERT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 1, 4));
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 4));  // the real answer
  EXPECT_EQ(r.out.frames, slice(fragments(3, 1, packet), 4, 8));
  EXPECT_EQ(r.seg.counters().ignored_acks, 4u);
}

TEST(PdopSegmenter, AfterCreditZeroTheNodeIsAskedAgain) {
  Rig r;
  const Bytes packet = counting(100);
  r.submit(3, 1, packet, 1);
  r.at(10ms);
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 0));
  EXPECT_EQ(r.seg.next_deadline(), t0 + 110ms);  // from the acknowledgement
  r.at(110ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 2));
  EXPECT_EQ(r.out.frames, slice(fragments(3, 1, packet), 4, 6));
}

TEST(PdopSegmenter, ARequestHoldsNewPacketsToThatNodeForAnAckTimeout) {
  Rig r;
  r.submit(3, 1, counting(40), 1);
  r.submit(4, 1, counting(40), 9);
  r.at(100ms);  // both time out: one request each
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3), pdop::ack_request(4)}));
  r.now = t0 + 150ms;
  // RPDO2 of node 3 is free, but an answer naming a finished packet may still be on its way.
  r.submit(3, 2, counting(8), 2);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.seg.queued(3, 2), 1u);
  r.submit(5, 2, counting(8), 3);  // another node: not held
  EXPECT_EQ(r.out.frames, fragments(5, 2, counting(8)));
  ASSERT_TRUE(r.ack(5, 2, AckStatus::complete, 1));
  r.at(200ms - 1ns);
  EXPECT_TRUE(r.out.frames.empty());
  r.at(200ms);  // the second requests: node 3 stays on hold while it is being asked
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3), pdop::ack_request(4)}));
  r.at(300ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3), pdop::ack_request(4)}));
  EXPECT_EQ(r.seg.next_deadline(), t0 + 400ms);
  r.at(400ms);  // RPDO1 gives up; no request since 300 ms, so RPDO2 goes
  EXPECT_EQ(r.out.frames,
            (Frames{abort_of(3, 1), fragments(3, 2, counting(8))[0], abort_of(4, 1)}));
  ASSERT_EQ(r.out.outcomes.size(), 2u);
  EXPECT_EQ(r.out.outcomes[0].result, PdopResult::timeout);
  EXPECT_EQ(r.out.outcomes[1].result, PdopResult::timeout);
  EXPECT_EQ(r.seg.active_request(3, 2), 2u);
}

// Why the hold: node 3 finished RPDO1's packet (its acknowledgement lost), then RPDO2's. Asked
// about RPDO1, the node has nothing open and answers with the last packet it finished: RPDO2's,
// status 1, 2 fragments. A 2-fragment packet on RPDO2 sent after the request would take that
// answer for its own completion, even though the node then aborts it.
TEST(PdopSegmenter, AnAnswerAboutAnEarlierPacketIsNotTakenForOneStartedAfterTheRequest) {
  sim::RpdopReceiver node(3, sim::PdopSpec{4096, 200ms, 4});
  Rig r;
  auto to_node = [&](const Frames& frames) {
    Frames acks;
    std::vector<sim::RpdopReceiver::Packet> packets;
    for (const Frame& f : frames) node.on_frame(f, r.now, acks, packets);
    return acks;
  };
  r.submit(3, 1, counting(4), 1);
  EXPECT_EQ(to_node(r.out.frames).size(), 1u);  // status 1, lost on the way
  r.submit(3, 2, counting(16), 2);
  const Frames ack2 = to_node(r.out.frames);
  ASSERT_EQ(ack2.size(), 1u);
  ASSERT_TRUE(r.frame(ack2[0]));
  EXPECT_EQ(r.only_outcome().request_id, 2u);

  r.at(100ms);
  ASSERT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  const Frames answer = to_node(r.out.frames);
  EXPECT_EQ(answer, (Frames{pdop::encode_ack(3, Ack{2, AckStatus::complete, 2, 4})}));
  r.now = t0 + 101ms;
  r.submit(3, 2, counting(16, 50), 3);
  EXPECT_TRUE(r.out.frames.empty());  // held
  r.now = t0 + 102ms;
  ASSERT_TRUE(r.frame(answer[0]));
  EXPECT_TRUE(r.out.outcomes.empty());  // about packet 2, not taken for packet 3

  // RPDO1 is never answered (the node's answer names RPDO2): it gives up at 400 ms and
  // RPDO2's packet goes. Its first fragment arrives twice: the node aborts it.
  for (const auto when : {200ms, 300ms}) {
    r.at(when);
    EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  }
  r.at(400ms);
  ASSERT_EQ(r.out.outcomes.size(), 1u);
  EXPECT_EQ(r.out.outcomes[0].request_id, 1u);
  EXPECT_EQ(r.out.outcomes[0].result, PdopResult::timeout);  // delivered, but never confirmed
  const Frames p3 = fragments(3, 2, counting(16, 50));
  ASSERT_EQ(r.out.frames, (Frames{abort_of(3, 1), p3[0], p3[1]}));
  const Frames acks = to_node({abort_of(3, 1), p3[0], p3[0], p3[1]});
  ASSERT_EQ(acks.size(), 2u);
  ASSERT_TRUE(r.frame(acks[0]));  // 0x85 for RPDO1
  EXPECT_TRUE(r.out.outcomes.empty());
  ASSERT_TRUE(r.frame(acks[1]));  // 0x80 for RPDO2
  EXPECT_EQ(r.only_outcome().request_id, 3u);
  EXPECT_EQ(r.only_outcome().result, PdopResult::receiver_abort);
  EXPECT_EQ(r.only_outcome().status, AckStatus::toggle_error);
}

// docs/pdop.md 4.2: the node acknowledges every `window` fragments of its own. A module window
// below the node's leaves the first burst unacknowledged until ack_timeout and a request.
TEST(PdopSegmenter, AFirstWindowBelowTheNodesWaitsForARequest) {
  sim::RpdopReceiver node(3, sim::PdopSpec{4096, 200ms, 4});
  Rig r({.window = 2});
  Frames acks;
  std::vector<sim::RpdopReceiver::Packet> packets;
  r.submit(3, 1, counting(40), 1);  // 5 fragments
  for (const Frame& f : r.out.frames) node.on_frame(f, r.now, acks, packets);
  EXPECT_TRUE(acks.empty());  // 2 of the node's 4: no acknowledgement
  r.at(100ms);
  ASSERT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  node.on_frame(r.out.frames[0], r.now, acks, packets);
  ASSERT_EQ(acks, (Frames{pdop::encode_ack(3, Ack{1, AckStatus::in_progress, 2, 4})}));
  ASSERT_TRUE(r.frame(acks[0]));
  acks.clear();
  for (const Frame& f : r.out.frames) node.on_frame(f, r.now, acks, packets);
  ASSERT_EQ(acks.size(), 1u);
  ASSERT_TRUE(r.frame(acks[0]));
  EXPECT_EQ(r.only_outcome().result, PdopResult::complete);
  EXPECT_EQ(r.only_outcome().elapsed, 100ms);
  ASSERT_EQ(packets.size(), 1u);
  EXPECT_EQ(packets[0].bytes, counting(40));
}

TEST(PdopSegmenter, OneRequestPerNodeAndInstantServesAllItsRpdos) {
  Rig r;
  r.submit(3, 1, counting(40), 1);
  r.submit(3, 4, counting(40), 2);
  r.at(100ms);
  EXPECT_EQ(r.out.frames, (Frames{pdop::ack_request(3)}));
  // The node answers for both (section 4.3): each goes back to its own `received`.
  ASSERT_TRUE(r.ack(3, 1, AckStatus::in_progress, 4, 4));
  EXPECT_EQ(r.out.frames, slice(fragments(3, 1, counting(40)), 4, 5));
  ASSERT_TRUE(r.ack(3, 4, AckStatus::in_progress, 3, 4));
  EXPECT_EQ(r.out.frames, slice(fragments(3, 4, counting(40)), 3, 5));
  EXPECT_EQ(r.seg.counters().ack_requests, 1u);
}

// ---- Cancel ------------------------------------------------------------------------------------

TEST(PdopSegmenter, CancelAbortsTheTransferOrDropsTheWaitingPacket) {
  Rig r;
  r.submit(3, 1, counting(40), 1);
  r.submit(3, 1, counting(16), 2);
  r.submit(3, 1, counting(16), 3);
  r.now += 5ms;
  r.clear();
  ASSERT_TRUE(r.seg.cancel(2, r.now, r.out));  // waiting: no frame
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.only_outcome().result, PdopResult::cancelled);
  EXPECT_EQ(r.only_outcome().fragments_sent, 0u);
  EXPECT_EQ(r.only_outcome().elapsed, 5ms);
  r.clear();
  ASSERT_TRUE(r.seg.cancel(1, r.now, r.out));  // in transfer: the sender abort
  EXPECT_EQ(r.out.frames, (Frames{abort_of(3, 1)}));
  EXPECT_EQ(r.only_outcome().result, PdopResult::cancelled);
  EXPECT_EQ(r.only_outcome().request_id, 1u);
  EXPECT_EQ(r.only_outcome().fragments_sent, 4u);
  r.clear();
  EXPECT_FALSE(r.seg.cancel(1, r.now, r.out));
  EXPECT_FALSE(r.seg.cancel(99, r.now, r.out));
  ASSERT_TRUE(r.ack(3, 1, AckStatus::sender_abort, 2));
  EXPECT_EQ(r.out.frames, fragments(3, 1, counting(16)));
  EXPECT_EQ(r.seg.counters().cancelled, 2u);
}

TEST(PdopSegmenter, CancelNodeEndsEveryPacketToIt) {
  Rig r;
  r.submit(8, 1, counting(40), 1);
  r.submit(8, 1, counting(40), 2);
  r.submit(8, 3, counting(4), 3);
  r.submit(9, 1, counting(4), 4);
  r.clear();
  EXPECT_EQ(r.seg.cancel_node(8, r.now, r.out), 3u);
  EXPECT_EQ(r.out.frames, (Frames{abort_of(8, 1), abort_of(8, 3)}));
  ASSERT_EQ(r.out.outcomes.size(), 3u);
  for (const PdopOutcome& o : r.out.outcomes) EXPECT_EQ(o.result, PdopResult::cancelled);
  EXPECT_EQ(r.seg.active_request(9, 1), 4u);
  EXPECT_EQ(r.seg.held_bytes(), 4u);
}

// ---- Concurrency and node ids -------------------------------------------------------------------

TEST(PdopSegmenter, TwoNodesConcurrentlyAtTheEdgeIdsOneAndThirtyOne) {
  Rig r({.window = 2});
  const Bytes a = counting(40);      // node 1, RPDO1: 0x201.., acks on 0x681
  const Bytes b = counting(33, 77);  // node 31, RPDO4: 0x51F.., acks on 0x69F
  const Frames fa = fragments(1, 1, a);
  const Frames fb = fragments(31, 4, b);
  EXPECT_EQ(fa[0].id, 0x221u);
  EXPECT_EQ(fb[0].id, 0x53Fu);
  r.submit(1, 1, a, 100);
  EXPECT_EQ(r.out.frames, slice(fa, 0, 2));
  r.submit(31, 4, b, 200);
  EXPECT_EQ(r.out.frames, slice(fb, 0, 2));

  ASSERT_TRUE(r.frame(Frame::standard(0x69F, {4, 0, 2, 0, 2})));
  EXPECT_EQ(r.out.frames, slice(fb, 2, 4));
  ASSERT_TRUE(r.frame(Frame::standard(0x681, {1, 0, 2, 0, 2})));
  EXPECT_EQ(r.out.frames, slice(fa, 2, 4));
  // An acknowledgement of node 1 naming RPDO4 is not node 31's.
  ASSERT_TRUE(r.frame(Frame::standard(0x681, {4, 0, 4, 0, 2})));
  EXPECT_TRUE(r.out.frames.empty());
  ASSERT_TRUE(r.frame(Frame::standard(0x69F, {4, 0, 4, 0, 2})));
  EXPECT_EQ(r.out.frames, slice(fb, 4, 5));
  ASSERT_TRUE(r.frame(Frame::standard(0x69F, {4, 1, 5, 0, 2})));
  EXPECT_EQ(r.only_outcome().request_id, 200u);
  EXPECT_EQ(r.seg.active_request(1, 1), 100u);
  ASSERT_TRUE(r.frame(Frame::standard(0x681, {1, 0, 4, 0, 2})));
  EXPECT_EQ(r.out.frames, slice(fa, 4, 5));
  ASSERT_TRUE(r.frame(Frame::standard(0x681, {1, 1, 5, 0, 2})));
  EXPECT_EQ(r.only_outcome().request_id, 100u);
  EXPECT_EQ(r.seg.counters().complete, 2u);
}

TEST(PdopSegmenter, AddressesOutsideThePdopRangeAreRefused) {
  Rig r;
  for (const auto& [node, rpdo] : std::vector<std::pair<NodeId, unsigned>>{
           {0, 1}, {32, 1}, {127, 1}, {1, 0}, {1, 5}, {31, 0}}) {
    r.submit(node, rpdo, counting(4), 42);
    EXPECT_TRUE(r.out.frames.empty());
    EXPECT_EQ(r.only_outcome().result, PdopResult::refused_address) << int{node} << " " << rpdo;
    EXPECT_EQ(r.only_outcome().request_id, 42u);
  }
  EXPECT_EQ(r.seg.active_request(0, 1), std::nullopt);
  EXPECT_EQ(r.seg.queued(32, 1), 0u);
  r.submit(1, 1, counting(4), 1);
  r.submit(31, 4, counting(4), 2);
  EXPECT_EQ(r.seg.active_request(1, 1), 1u);
  EXPECT_EQ(r.seg.active_request(31, 4), 2u);
}

TEST(PdopSegmenter, OversizeAndEmptyPacketsAreRefused) {
  Rig r({.max_packet_bytes = 16, .max_held_bytes = 40});
  r.submit(3, 1, counting(17), 1);
  EXPECT_EQ(r.only_outcome().result, PdopResult::refused_size);
  EXPECT_TRUE(r.out.frames.empty());
  r.submit(3, 1, {}, 2);
  EXPECT_EQ(r.only_outcome().result, PdopResult::refused_size);
  r.submit(3, 1, counting(16), 3);
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_EQ(r.out.frames.size(), 2u);
  // max_held_bytes counts every packet held on the bus.
  r.submit(4, 1, counting(16), 4);
  EXPECT_TRUE(r.out.outcomes.empty());
  r.submit(5, 1, counting(9), 5);
  EXPECT_EQ(r.only_outcome().result, PdopResult::refused_busy);
  r.submit(5, 1, counting(8), 6);
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_EQ(r.seg.held_bytes(), 40u);
  EXPECT_EQ(r.seg.counters().refused, 3u);
  EXPECT_EQ(r.seg.counters().submitted, 6u);
}

TEST(PdopSegmenter, QueueOfZeroRefusesASecondPacket) {
  Rig r({.queue_per_rpdo = 0});
  r.submit(3, 1, counting(4), 1);
  EXPECT_TRUE(r.out.outcomes.empty());
  r.submit(3, 1, counting(4), 2);
  EXPECT_EQ(r.only_outcome().result, PdopResult::refused_busy);
  r.submit(3, 2, counting(4), 3);  // another RPDO of the node is free
  EXPECT_TRUE(r.out.outcomes.empty());
}

// ---- Frames that are not for it -----------------------------------------------------------------

TEST(PdopSegmenter, FramesThatAreNotAcknowledgementsAreIgnored) {
  Rig r;
  r.submit(3, 1, counting(100), 1);
  const auto before = r.seg.counters();
  const auto deadline = r.seg.next_deadline();
  Frame extended = Frame::standard(0x683, {1, 1, 13, 0, 4});
  extended.flags = can::FrameFlags::extended;
  Frame error = Frame::standard(0x683, {1, 1, 13, 0, 4});
  error.flags = can::FrameFlags::error;
  for (const Frame& f : Frames{Frame::standard(0x703, {0x05}),     // heartbeat
                               Frame::standard(0x203, {1, 2, 3}),  // an RPDO (another master's)
                               Frame::standard(0x183, {1, 2}),     // TPDO
                               Frame::standard(0x583, {0x60, 0, 0, 0, 0, 0, 0, 0}),  // SDO
                               pdop::ack_request(3),                   // a request (remote frame)
                               Frame::standard(0x683, {1, 1, 13, 0}),  // 4 bytes
                               Frame::standard(0x683, {1, 1, 13, 0, 4, 0}),  // 6 bytes
                               Frame::standard(0x683, {0, 1, 13, 0, 4}),     // RPDO 0
                               Frame::standard(0x683, {5, 1, 13, 0, 4}),     // RPDO 5
                               Frame::standard(0x680, {1, 1, 13, 0, 4}),     // node 0
                               Frame::standard(0x6A0, {1, 1, 13, 0, 4}),     // beyond node 31
                               Frame::standard(0x6E3, {1, 1, 13, 0, 4}), extended, error}) {
    EXPECT_FALSE(r.frame(f)) << can::to_string(f);
    EXPECT_TRUE(r.out.frames.empty());
    EXPECT_TRUE(r.out.outcomes.empty());
  }
  // Acknowledgements for no transfer, or with undefined status codes: looked at, ignored.
  EXPECT_TRUE(r.ack(4, 1, AckStatus::complete, 13));
  EXPECT_TRUE(r.ack(3, 2, AckStatus::complete, 13));
  EXPECT_TRUE(r.raw_ack(3, 1, 0x02, 13));
  EXPECT_TRUE(r.raw_ack(3, 1, 0x7F, 4));
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.outcomes.empty());
  EXPECT_EQ(r.seg.counters().ignored_acks, before.ignored_acks + 4);
  EXPECT_EQ(r.seg.counters().acks, before.acks);
  EXPECT_EQ(r.seg.next_deadline(), deadline);
  EXPECT_EQ(r.seg.active_request(3, 1), 1u);
}

// ---- Options ------------------------------------------------------------------------------------

TEST(PdopSegmenter, DefaultsAreThoseOfTheDocument) {
  const PdopSegmenterOptions o;
  EXPECT_EQ(o.max_packet_bytes, 4096u);
  EXPECT_EQ(o.window, 4u);
  EXPECT_EQ(o.ack_timeout, 100ms);
  EXPECT_EQ(o.retries, 3u);
  EXPECT_TRUE(validate(o).empty());
}

TEST(PdopSegmenter, OptionsAreValidatedWithEveryProblemNamed) {
  EXPECT_TRUE(validate({.max_packet_bytes = pdop::kMaxPacketBytes,
                        .window = 255,
                        .ack_timeout = 10s,
                        .retries = 10,
                        .queue_per_rpdo = 1024,
                        .max_held_bytes = std::size_t{1} << 30})
                  .empty());
  EXPECT_TRUE(validate({.max_packet_bytes = 1,
                        .window = 1,
                        .ack_timeout = 1ms,
                        .retries = 0,
                        .queue_per_rpdo = 0,
                        .max_held_bytes = 1})
                  .empty());
  const auto problems = validate({.max_packet_bytes = pdop::kMaxPacketBytes + 1,
                                  .window = 0,
                                  .ack_timeout = 0ms,
                                  .retries = 11,
                                  .queue_per_rpdo = 1025,
                                  .max_held_bytes = 100});
  ASSERT_EQ(problems.size(), 6u);
  EXPECT_EQ(problems[0], "max_packet_bytes: 524281 is outside 1..524280");
  EXPECT_EQ(problems[1], "window: 0 is outside 1..255");
  EXPECT_EQ(problems[2], "ack_timeout: 0 ms is outside 1 ms..10 s");
  EXPECT_EQ(problems[3], "retries: 11 is outside 0..10");
  EXPECT_EQ(problems[4], "queue_per_rpdo: 1025 is outside 0..1024");
  EXPECT_EQ(problems[5], "max_held_bytes: 100 is outside max_packet_bytes (524281)..1073741824");
  EXPECT_EQ(validate({.max_packet_bytes = 0}).size(), 1u);
  EXPECT_EQ(validate({.ack_timeout = 10001ms}).size(), 1u);
  EXPECT_THROW(PdopSegmenter({.window = 0}), std::invalid_argument);
  EXPECT_THROW((PdopSegmenter({.max_packet_bytes = 8192, .max_held_bytes = 4096})),
               std::invalid_argument);
}

TEST(PdopSegmenter, OutcomeReadsAsOneLogLine) {
  EXPECT_EQ(to_string(PdopOutcome{.request_id = 7,
                                  .node = 3,
                                  .rpdo = 1,
                                  .result = PdopResult::receiver_abort,
                                  .status = AckStatus::toggle_error,
                                  .fragments = 5,
                                  .fragments_sent = 6,
                                  .retransmissions = 1,
                                  .ack_requests = 1,
                                  .elapsed = 12ms}),
            "request 7 node 3 RPDO1: receiver_abort 0x80 (5 fragments, 6 sent, 1 again, 1 "
            "request, 12 ms)");
  EXPECT_STREQ(to_string(PdopResult::refused_address), "refused_address");
}

// ---- Property: against the simulated node over a lossy bus --------------------------------------

// The faults the protocol is built to survive (docs/pdop.md): lost and duplicated
// acknowledgements and requests, duplicated fragments and abort frames, a lost fragment followed
// by one that arrives, delays shorter than half an ack_timeout each way (frames of one
// direction stay in order, as on CAN), and whole seconds in which no acknowledgement gets
// through. Left out, because no sender can tell (see the report of this test): two consecutive
// fragments of a stream lost, the only fragment of a packet lost, a lost abort frame, a
// duplicated final fragment with t = 0 (a one-frame packet of its own) and a duplicated
// status-1 acknowledgement.
struct Faults {
  double fragment_loss = 0.01;  // one lost fragment aborts the packet: 0.99^64 = 53% of 512 B
  double fragment_dup = 0.005;
  double request_loss = 0.2;
  double request_dup = 0.05;
  double abort_dup = 0.2;
  double ack_loss = 0.05;
  double ack_dup = 0.05;
  Duration max_delay = 20ms;
  double blackout_per_second = 0.1;  // chance that a second has acks blacked out
  Duration blackout = 600ms;
  // The faults left out, each breaking the property when turned on alone.
  bool lose_consecutive_fragments = false;
  bool lose_only_fragment = false;
  double abort_loss = 0;
  bool dup_final_t0 = false;
  bool dup_complete_ack = false;
};

struct Stream {
  NodeId node;
  unsigned rpdo;
};

struct Totals {
  std::uint64_t submitted = 0, complete = 0, receiver_aborts = 0, timeouts = 0, cancelled = 0,
                refused = 0, retransmissions = 0, delivered_despite_failure = 0, requests = 0;
};

class LossyBusRun {
 public:
  // `intercepted`: failures caught by a fake reporter also stop the run.
  LossyBusRun(std::uint32_t seed, const Faults& faults, Totals& totals,
              const ::testing::TestPartResultArray* intercepted = nullptr)
      : rng_(seed), faults_(faults), totals_(totals), intercepted_(intercepted) {
    max_packet_ = std::size_t{8} << (rng_() % 7);  // 8..512
    if (seed % 5 == 0) max_packet_ = 4096;
    sender_window_ = static_cast<std::uint8_t>(1 + rng_() % 8);
    options_ = PdopSegmenterOptions{.max_packet_bytes = max_packet_,
                                    .window = sender_window_,
                                    .ack_timeout = 100ms,
                                    .retries = static_cast<unsigned>(rng_() % 4),
                                    .queue_per_rpdo = 1 + rng_() % 3};
    seg_.emplace(options_);
    const std::vector<NodeId> nodes = {1, 17, 31};
    for (NodeId node : nodes) {
      // At most the sender's first window: a node acknowledging less often than that would
      // leave every packet's first window waiting for ack_timeout (see the report).
      const auto node_window = static_cast<std::uint8_t>(1 + rng_() % sender_window_);
      receivers_.emplace(node,
                         sim::RpdopReceiver(node, sim::PdopSpec{max_packet_, 200ms, node_window}));
    }
    streams_ = {{1, 1}, {17, 2}, {31, 4}};
    if (seed % 2 == 0) streams_.push_back({17, 3});  // two RPDOs of one node at once
  }

  void run(int packets) {
    // Submission times: bursts and gaps over the run.
    TimePoint at = t0;
    for (int i = 0; i < packets; ++i) {
      at += std::chrono::milliseconds(rng_() % 4 == 0 ? 0 : rng_() % 120);
      submits_.push_back({at, streams_[rng_() % streams_.size()]});
    }
    TimePoint now = t0;
    for (int step = 0;; ++step) {
      ASSERT_LT(step, 5'000'000) << "no end";
      TimePoint next = TimePoint::max();
      if (!submits_.empty()) next = std::min(next, submits_.front().first);
      if (!down_.empty()) next = std::min(next, down_.front().first);
      if (!up_.empty()) next = std::min(next, up_.front().first);
      if (const auto d = seg_->next_deadline()) next = std::min(next, *d);
      if (next == TimePoint::max()) break;
      ASSERT_GE(next, now);
      now = next;
      while (!down_.empty() && down_.front().first <= now) {
        const Frame f = down_.front().second;
        down_.pop_front();
        deliver_down(f, now);
        if (stopped()) return;
      }
      while (!up_.empty() && up_.front().first <= now) {
        const Frame f = up_.front().second;
        up_.pop_front();
        deliver_up(f, now);
        if (stopped()) return;
      }
      if (const auto d = seg_->next_deadline(); d && *d <= now) {
        PdopSegmenter::Output out;
        seg_->tick(now, out);
        take(out, now);
        if (stopped()) return;
      }
      while (!submits_.empty() && submits_.front().first <= now) {
        const Stream s = submits_.front().second;
        submits_.pop_front();
        submit(s, now);
        if (stopped()) return;
      }
      // Now and then the surface gives up on a packet in transfer.
      if (rng_() % 400 == 0) {
        const Stream s = streams_[rng_() % streams_.size()];
        if (const auto id = seg_->active_request(s.node, s.rpdo)) {
          PdopSegmenter::Output out;
          ASSERT_TRUE(seg_->cancel(*id, now, out));
          take(out, now);
          if (stopped()) return;
        }
      }
    }
    check_end();
  }

 private:
  struct Request {
    Stream stream;
    Bytes bytes;
    // (t, c, fragment bytes) -> fragment index
    std::map<std::tuple<bool, bool, Bytes>, std::uint32_t> index;
    std::uint32_t allowed = 0;  // fragments below this are covered by some credit
    std::optional<PdopOutcome> outcome;
    int delivered = 0;
  };

  Bytes random_packet(const Stream& s) {
    for (;;) {
      std::size_t size = rng_() % 4 == 0 ? 1 + rng_() % 8 : 1 + rng_() % max_packet_;
      if (size < 3) size = 3 + rng_() % 6;  // keep packets of one stream distinct
      Bytes bytes(size);
      for (auto& b : bytes) b = static_cast<std::uint8_t>(rng_());
      if (used_.insert({key(s), bytes}).second) return bytes;
    }
  }
  static unsigned key(const Stream& s) { return s.node * 8u + s.rpdo; }

  void submit(const Stream& s, TimePoint now) {
    const std::uint64_t id = ++last_id_;
    Request r{s, random_packet(s), {}, sender_window_, std::nullopt, 0};
    const Frames frames = fragments(s.node, s.rpdo, r.bytes);
    for (std::uint32_t k = 0; k < frames.size(); ++k) {
      const pdop::FragmentId fid = pdop::decode(frames[k].id);
      const auto p = frames[k].payload();
      ASSERT_TRUE(
          r.index.emplace(std::tuple{fid.toggle, fid.continued, Bytes(p.begin(), p.end())}, k)
              .second);
    }
    by_bytes_[{key(s), r.bytes}] = id;
    Bytes copy = r.bytes;
    requests_.emplace(id, std::move(r));
    ++totals_.submitted;
    PdopSegmenter::Output out;
    seg_->submit(s.node, s.rpdo, std::move(copy), id, now, out);
    take(out, now);
  }

  // Everything the segmenter said: outcomes are checked, frames checked and put on the bus.
  void take(const PdopSegmenter::Output& out, TimePoint now) {
    for (const PdopOutcome& o : out.outcomes) {
      auto it = requests_.find(o.request_id);
      ASSERT_NE(it, requests_.end());
      ASSERT_FALSE(it->second.outcome.has_value()) << "second outcome: " << to_string(o);
      ASSERT_EQ(o.node, it->second.stream.node);
      ASSERT_EQ(o.rpdo, it->second.stream.rpdo);
      it->second.outcome = o;
      switch (o.result) {
        case PdopResult::complete:
          ++totals_.complete;
          break;
        case PdopResult::receiver_abort:
          ++totals_.receiver_aborts;
          break;
        case PdopResult::timeout:
          ++totals_.timeouts;
          break;
        case PdopResult::cancelled:
          ++totals_.cancelled;
          break;
        default:
          ++totals_.refused;
          break;
      }
      totals_.retransmissions += o.retransmissions;
      totals_.requests += o.ack_requests;
    }
    for (const Frame& f : out.frames) {
      if (f.is_remote()) {
        ASSERT_EQ(f, pdop::ack_request(static_cast<NodeId>(f.id & 0x1F)));
        if (chance(faults_.request_loss)) continue;
        send_down(f, now);
        if (chance(faults_.request_dup)) send_down(f, now);
        continue;
      }
      const pdop::FragmentId fid = pdop::decode(f.id);
      const auto rpdo = pdop::rpdo_number(fid.function_code);
      ASSERT_TRUE(rpdo.has_value()) << can::to_string(f);
      const Stream s{fid.node, *rpdo};
      bool& lost_before = last_lost_[key(s)];
      if (f.len == 0 && !fid.continued) {  // abort frame
        if (chance(faults_.abort_loss)) continue;
        lost_before = false;
        send_down(f, now);
        if (chance(faults_.abort_dup)) send_down(f, now);
        continue;
      }
      // A fragment: of the request in transfer on its stream, within the credit.
      const auto active = seg_->active_request(s.node, s.rpdo);
      ASSERT_TRUE(active.has_value()) << can::to_string(f);
      Request& r = requests_.at(*active);
      const auto p = f.payload();
      const auto k = r.index.find(std::tuple{fid.toggle, fid.continued, Bytes(p.begin(), p.end())});
      ASSERT_NE(k, r.index.end()) << "not a fragment of request " << *active << ": "
                                  << can::to_string(f);
      ASSERT_LT(k->second, r.allowed) << "fragment " << k->second << " of request " << *active
                                      << " beyond every credit the node gave";
      const bool only = r.index.size() == 1;
      if ((!only || faults_.lose_only_fragment) &&
          (!lost_before || faults_.lose_consecutive_fragments) && chance(faults_.fragment_loss)) {
        lost_before = true;
        continue;
      }
      lost_before = false;
      send_down(f, now);
      const bool one_frame_packet_of_its_own = !fid.continued && !fid.toggle;
      if ((!one_frame_packet_of_its_own || faults_.dup_final_t0) && chance(faults_.fragment_dup)) {
        send_down(f, now);
      }
    }
  }

  void deliver_down(const Frame& f, TimePoint now) {
    for (auto& [node, rx] : receivers_) {
      std::vector<Frame> acks;
      std::vector<sim::RpdopReceiver::Packet> packets;
      rx.on_frame(f, now, acks, packets);
      for (const auto& packet : packets) {
        const Stream s{node, packet.rpdo};
        const auto it = by_bytes_.find({key(s), packet.bytes});
        ASSERT_NE(it, by_bytes_.end())
            << "node " << int{node} << " RPDO" << packet.rpdo << " delivered "
            << packet.bytes.size() << " bytes that no request sent";
        Request& r = requests_.at(it->second);
        ++r.delivered;
        ASSERT_EQ(r.delivered, 1) << "request " << it->second << " delivered twice";
      }
      for (const Frame& a : acks) {
        const auto ack = pdop::decode_ack(a);
        ASSERT_TRUE(ack.has_value());
        if (blacked_out(now) || chance(faults_.ack_loss)) continue;
        send_up(a, now);
        if ((ack->status != AckStatus::complete || faults_.dup_complete_ack) &&
            chance(faults_.ack_dup)) {
          send_up(a, now);
        }
      }
    }
  }

  void deliver_up(const Frame& f, TimePoint now) {
    const auto ack = pdop::decode_ack(f);
    ASSERT_TRUE(ack.has_value());
    const NodeId node = static_cast<NodeId>(f.id & 0x1F);
    const auto active = seg_->active_request(node, ack->rpdo);
    if (active && ack->status == AckStatus::in_progress) {
      Request& r = requests_.at(*active);
      r.allowed = std::max<std::uint32_t>(r.allowed, std::uint32_t{ack->received} + ack->credit);
    }
    PdopSegmenter::Output out;
    ASSERT_TRUE(seg_->on_frame(f, now, out));
    take(out, now);
  }

  void check_end() {
    for (const Stream& s : streams_) {
      EXPECT_EQ(seg_->active_request(s.node, s.rpdo), std::nullopt);
      EXPECT_EQ(seg_->queued(s.node, s.rpdo), 0u);
    }
    EXPECT_EQ(seg_->held_bytes(), 0u);
    for (const auto& [id, r] : requests_) {
      ASSERT_TRUE(r.outcome.has_value()) << "request " << id << " never ended (silent loss)";
      if (r.outcome->result == PdopResult::complete) {
        EXPECT_EQ(r.delivered, 1) << "request " << id << " complete but not delivered";
        EXPECT_GE(r.outcome->fragments_sent, r.outcome->fragments);
      } else {
        EXPECT_LE(r.delivered, 1);
        if (r.delivered == 1) ++totals_.delivered_despite_failure;
      }
      if (r.outcome->result == PdopResult::refused_busy) {
        EXPECT_EQ(r.delivered, 0);
      }
    }
  }

  bool stopped() const {
    return ::testing::Test::HasFatalFailure() ||
           (intercepted_ != nullptr && intercepted_->size() > 0);
  }
  bool chance(double p) { return std::uniform_real_distribution<double>(0, 1)(rng_) < p; }
  Duration delay() {
    const auto max_us = std::chrono::duration_cast<std::chrono::microseconds>(faults_.max_delay);
    return std::chrono::microseconds(rng_() % static_cast<std::uint64_t>(max_us.count() + 1));
  }
  // Frames of one direction keep their order, as on a CAN bus.
  void send_down(const Frame& f, TimePoint now) {
    const TimePoint at = std::max(now + delay(), down_.empty() ? now : down_.back().first);
    down_.emplace_back(at, f);
  }
  void send_up(const Frame& f, TimePoint now) {
    const TimePoint at = std::max(now + delay(), up_.empty() ? now : up_.back().first);
    up_.emplace_back(at, f);
  }
  bool blacked_out(TimePoint now) {
    const auto second = std::chrono::duration_cast<std::chrono::seconds>(now - t0).count();
    auto [it, fresh] = blackouts_.try_emplace(second, false);
    if (fresh) it->second = chance(faults_.blackout_per_second);
    return it->second && now - t0 - std::chrono::seconds(second) < faults_.blackout;
  }

  std::mt19937 rng_;
  Faults faults_;
  Totals& totals_;
  const ::testing::TestPartResultArray* intercepted_;
  std::size_t max_packet_ = 0;
  std::uint8_t sender_window_ = 4;
  PdopSegmenterOptions options_;
  std::optional<PdopSegmenter> seg_;
  std::map<NodeId, sim::RpdopReceiver> receivers_;
  std::vector<Stream> streams_;
  std::deque<std::pair<TimePoint, Stream>> submits_;
  std::deque<std::pair<TimePoint, Frame>> down_, up_;
  std::map<std::uint64_t, Request> requests_;
  std::map<std::pair<unsigned, Bytes>, std::uint64_t> by_bytes_;
  std::set<std::pair<unsigned, Bytes>> used_;
  std::map<unsigned, bool> last_lost_;
  std::map<long long, bool> blackouts_;
  std::uint64_t last_id_ = 0;
};

TEST(PdopSegmenterProperty, EveryPacketIsDeliveredExactlyOnceOrReportedAgainstTheSimulatedNode) {
  Totals totals;
  for (std::uint32_t seed = 1; seed <= 24; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    LossyBusRun run(seed, Faults{}, totals);
    run.run(250);
    if (HasFailure()) return;
  }
  std::cout << "submitted " << totals.submitted << ", complete " << totals.complete
            << ", receiver aborts " << totals.receiver_aborts << ", timeouts " << totals.timeouts
            << ", cancelled " << totals.cancelled << ", refused " << totals.refused
            << ", retransmissions " << totals.retransmissions << ", requests " << totals.requests
            << ", delivered despite a reported failure " << totals.delivered_despite_failure
            << "\n";
  // Not vacuous: most packets complete and every recovery path was taken.
  EXPECT_GT(totals.complete, totals.submitted / 2);
  EXPECT_GT(totals.receiver_aborts, 0u);
  EXPECT_GT(totals.timeouts, 0u);
  EXPECT_GT(totals.cancelled, 0u);
  EXPECT_GT(totals.retransmissions, 0u);
  EXPECT_GT(totals.requests, 0u);
}

TEST(PdopSegmenterProperty, CleanBusCompletesEverything) {
  Totals totals;
  Faults clean;
  clean.fragment_loss = clean.fragment_dup = clean.request_loss = clean.request_dup = 0;
  clean.abort_dup = clean.ack_loss = clean.ack_dup = clean.blackout_per_second = 0;
  for (std::uint32_t seed = 100; seed < 108; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    LossyBusRun run(seed, clean, totals);
    run.run(200);
    if (HasFailure()) return;
  }
  EXPECT_EQ(totals.complete + totals.refused + totals.cancelled, totals.submitted);
  EXPECT_EQ(totals.receiver_aborts, 0u);
  EXPECT_EQ(totals.timeouts, 0u);
  EXPECT_EQ(totals.retransmissions, 0u);
}

TEST(PdopSegmenterProperty, HeavierFaultsKeepTheProperty) {
  Totals totals;
  Faults heavy;
  heavy.fragment_loss = 0.1;
  heavy.fragment_dup = 0.05;
  heavy.ack_loss = 0.2;
  heavy.ack_dup = 0.2;
  heavy.blackout_per_second = 0.3;
  for (std::uint32_t seed = 200; seed < 210; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    LossyBusRun run(seed, heavy, totals);
    run.run(250);
    if (HasFailure()) return;
  }
  EXPECT_GT(totals.complete, 0u);
}

// The faults the property test leaves out do break it: the limits of docs/pdop.md from the
// sender's side (see the report of this change). Should the protocol learn to tell them apart
// (a packet number in the acknowledgement, say), this test says so.
bool breaks_the_property(const Faults& faults) {
  ::testing::TestPartResultArray results;
  {
    ::testing::ScopedFakeTestPartResultReporter reporter(
        ::testing::ScopedFakeTestPartResultReporter::INTERCEPT_ONLY_CURRENT_THREAD, &results);
    Totals totals;
    for (std::uint32_t seed = 1; seed <= 60 && results.size() == 0; ++seed) {
      LossyBusRun run(seed, faults, totals, &results);
      run.run(250);
    }
  }
  return results.size() > 0;
}

TEST(PdopSegmenterProperty, FaultsNoSenderCanTellBreakIt) {
  Faults f;
  f.lose_consecutive_fragments = true;  // k+2 arrives with k's toggle: taken as k
  f.fragment_loss = 0.3;
  EXPECT_TRUE(breaks_the_property(f)) << "two consecutive fragments lost";
  f = Faults{};
  f.lose_only_fragment = true;  // the request is answered for the packet before
  f.fragment_loss = 0.3;
  EXPECT_TRUE(breaks_the_property(f)) << "every fragment of a packet lost";
  f = Faults{};
  f.abort_loss = 0.5;  // the next packet's t = 0 fragment continues the old one
  f.fragment_dup = 0.05;
  EXPECT_TRUE(breaks_the_property(f)) << "abort frame lost";
  f = Faults{};
  f.dup_final_t0 = true;  // a final fragment with t = 0 is a one-frame packet of its own
  f.fragment_dup = 0.1;
  EXPECT_TRUE(breaks_the_property(f)) << "final fragment with t = 0 duplicated";
  f = Faults{};
  f.dup_complete_ack = true;  // taken for the next packet of as many fragments
  f.ack_dup = 0.2;
  EXPECT_TRUE(breaks_the_property(f)) << "status-1 acknowledgement duplicated";
  f = Faults{};
  f.max_delay = 90ms;  // round trip beyond ack_timeout: a late acknowledgement is the answer
  EXPECT_TRUE(breaks_the_property(f)) << "round trip longer than ack_timeout";
}

}  // namespace
}  // namespace canbridge::bridge
