// The surface's store-and-forward RPDOP receiver (docs/pdop.md section 4, issue 6): explicit
// exchanges with hand-made fragments and injected times (pacing, the forwarded phase and its
// outcomes, stale outcomes, outcome timeout, fail_forwarded, every receiver abort and the
// resynchronisation, requests, relayed nodes, interleaving, options), then an end-to-end property
// test with the gateway's real sender (bridge::PdopSegmenter) on a direct channel, the test
// playing the gateway's outcomes after random delays.
#include "routing/rpdop_relay.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <iostream>
#include <map>
#include <numeric>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "can/frame.hpp"
#include "canopen/pdop.hpp"
#include "routing/pdop_segmenter.hpp"
#include "tests/bridge/rpdop_test_helpers.hpp"

namespace canbridge::bridge {
namespace {

using namespace rpdop_test;

namespace pdop = canopen::pdop;
using namespace std::chrono_literals;
using can::Frame;
using pdop::Ack;
using pdop::AckStatus;
using TimePoint = RpdopRelay::TimePoint;
using Duration = RpdopRelay::Clock::duration;

Frame ack(NodeId node, std::uint8_t rpdo, AckStatus status, std::uint16_t received,
          std::uint8_t credit) {
  return pdop::encode_ack(node, Ack{rpdo, status, received, credit});
}
Frame raw_ack(NodeId node, std::uint8_t rpdo, std::uint8_t status, std::uint16_t received,
              std::uint8_t credit) {
  return ack(node, rpdo, static_cast<AckStatus>(status), received, credit);
}
// A fragment built by hand: any t, c and length.
Frame fragment_frame(NodeId node, unsigned rpdo, bool t, bool c,
                     std::initializer_list<std::uint8_t> data) {
  const pdop::FragmentId id{static_cast<std::uint8_t>(pdop::rpdo_base(rpdo) >> 7), t, c, node};
  return Frame::standard(pdop::encode(id), data);
}

// One relay at an injected time; every call starts with an empty output.
struct RelayRig {
  explicit RelayRig(RpdopRelayOptions options = {}, std::initializer_list<NodeId> nodes = {3})
      : relay(options) {
    for (NodeId n : nodes) relay.set_relayed(n, true);
  }

  bool frame(const Frame& f) {
    clear();
    return relay.on_frame(f, now, out);
  }
  // Every frame at the current time; the output of all of them.
  void frames(const Frames& fs) {
    clear();
    for (const Frame& f : fs) EXPECT_TRUE(relay.on_frame(f, now, out)) << can::to_string(f);
  }
  Frames request(NodeId node) {
    EXPECT_TRUE(frame(pdop::ack_request(node)));
    return out.frames;
  }
  void outcome(std::uint64_t id, AckStatus status) {
    clear();
    relay.on_outcome(id, status, out);
  }
  void at(Duration since_t0) {
    now = t0 + since_t0;
    clear();
    relay.tick(now, out);
  }
  void clear() {
    out.frames.clear();
    out.packets.clear();
  }
  // The one packet of the last call.
  RpdopRelay::Packet only_packet() const {
    EXPECT_EQ(out.packets.size(), 1u);
    return out.packets.empty() ? RpdopRelay::Packet{} : out.packets.front();
  }

  RpdopRelay relay;
  TimePoint now = t0;
  RpdopRelay::Output out;
};

// ---- The forwarded phase ------------------------------------------------------------------------

TEST(RpdopRelay, TwentyBytesWindowTwoIsForwardedAndCompletedOnlyByTheOutcome) {
  RelayRig r({.window = 2});
  const Bytes packet = counting(20);
  const Frames fs = fragments(3, 1, packet);
  ASSERT_EQ(fs.size(), 3u);

  EXPECT_TRUE(r.frame(fs[0]));
  EXPECT_TRUE(r.out.frames.empty());
  r.now += 1ms;
  EXPECT_TRUE(r.frame(fs[1]));
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::in_progress, 2, 2)}));
  EXPECT_TRUE(r.out.packets.empty());

  r.now += 1ms;
  EXPECT_TRUE(r.frame(fs[2]));
  EXPECT_TRUE(r.out.frames.empty()) << "no status 1 before the node's outcome";
  const auto p = r.only_packet();
  EXPECT_EQ(p.request_id, 1u);
  EXPECT_EQ(p.node, 3);
  EXPECT_EQ(p.rpdo, 1u);
  EXPECT_EQ(p.bytes, packet);
  EXPECT_EQ(r.relay.counters().packets, 1u);
  EXPECT_EQ(r.relay.next_deadline(), r.now + RpdopRelayOptions{}.outcome_timeout);

  // While forwarded, a request is answered "in progress, all of it, wait".
  r.now += 50ms;
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 3, 0)}));
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 3, 0)}));

  r.outcome(1, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::complete, 3, 2)}));
  EXPECT_EQ(r.relay.counters().completed, 1u);
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
  // The finished packet now answers requests.
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::complete, 3, 2)}));
  EXPECT_EQ(r.relay.counters().ack_requests, 3u);

  // The next packet on the RPDO gets the next id and starts from its first fragment.
  r.frames(fragments(3, 1, counting(9, 50)));
  EXPECT_EQ(r.only_packet().request_id, 2u);
  EXPECT_EQ(r.only_packet().bytes, counting(9, 50));
}

TEST(RpdopRelay, OneFramePacketIsForwardedAndAcknowledgedOnItsOutcome) {
  RelayRig r({.window = 4});
  EXPECT_TRUE(r.frame(Frame::standard(0x203, {7, 8, 9})));
  EXPECT_TRUE(r.out.frames.empty());
  const auto p = r.only_packet();
  EXPECT_EQ(p.bytes, (Bytes{7, 8, 9}));
  EXPECT_EQ(p.rpdo, 1u);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 1, 0)}));
  r.outcome(p.request_id, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::complete, 1, 4)}));
  // Eight bytes, the most a one-frame packet has, on RPDO4.
  EXPECT_TRUE(r.frame(Frame::standard(0x503, {1, 2, 3, 4, 5, 6, 7, 8})));
  EXPECT_EQ(r.only_packet().bytes, counting(8, 1));
  EXPECT_EQ(r.only_packet().rpdo, 4u);
}

class OutcomeAbort : public ::testing::TestWithParam<std::uint8_t> {};

TEST_P(OutcomeAbort, IsPassedToTheMasterWithAllFragmentsAndTheWindow) {
  RelayRig r({.window = 3});
  r.frames(fragments(3, 2, counting(30)));
  const auto p = r.only_packet();
  r.outcome(p.request_id, static_cast<AckStatus>(GetParam()));
  EXPECT_EQ(r.out.frames, (Frames{raw_ack(3, 2, GetParam(), 4, 3)}));
  EXPECT_EQ(r.relay.counters().failed, 1u);
  EXPECT_EQ(r.relay.counters().completed, 0u);
  EXPECT_EQ(r.request(3), (Frames{raw_ack(3, 2, GetParam(), 4, 3)}));
  // Closed by its c = 0 fragment: no resynchronisation, the next packet is taken at once.
  r.frames(fragments(3, 2, counting(12)));
  EXPECT_EQ(r.only_packet().bytes, counting(12));
}

INSTANTIATE_TEST_SUITE_P(RpdopRelay, OutcomeAbort,
                         ::testing::Values(0x80, 0x81, 0x82, 0x83, 0x84, 0x86, 0xFF));

TEST(RpdopRelay, OutcomeStatusesTheMasterCannotTakeBecome0x82) {
  for (const std::uint8_t status : {0x00, 0x02, 0x7F, 0x85}) {
    SCOPED_TRACE(status);
    RelayRig r({.window = 4});
    r.frames(fragments(3, 1, counting(5)));
    r.outcome(r.only_packet().request_id, static_cast<AckStatus>(status));
    EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::out_of_memory, 1, 4)}));
    EXPECT_EQ(r.relay.counters().failed, 1u);
  }
}

TEST(RpdopRelay, MastersAbortWhileForwardedMakesTheOutcomeStale) {
  RelayRig r({.window = 4});
  r.frames(fragments(3, 1, counting(20)));
  const auto id = r.only_packet().request_id;
  EXPECT_TRUE(r.frame(abort_of(3, 1)));
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::sender_abort, 3, 4)}));
  EXPECT_EQ(r.relay.counters().sender_aborts, 1u);
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);

  r.outcome(id, AckStatus::complete);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().stale_outcomes, 1u);
  EXPECT_EQ(r.relay.counters().completed, 0u);
  // An id never given out is stale as well.
  r.outcome(99, AckStatus::complete);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().stale_outcomes, 2u);
  // Outcomes are taken once: the second one for a finished id is stale.
  r.frames(fragments(3, 1, counting(3)));
  const auto next = r.only_packet().request_id;
  r.outcome(next, AckStatus::complete);
  EXPECT_EQ(r.out.frames.size(), 1u);
  r.outcome(next, AckStatus::complete);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().stale_outcomes, 3u);
}

TEST(RpdopRelay, FragmentsWhileForwardedAreDroppedUnanswered) {
  RelayRig r({.window = 4});
  const Frames fs = fragments(3, 1, counting(20));
  r.frames(fs);
  const auto id = r.only_packet().request_id;
  // The last fragment received twice (t = 0, c = 0: a one-frame packet if it were taken) and a
  // sender that did not wait for status 1.
  r.frames({fs[2], fs[0], fragment_frame(3, 1, true, true, {1, 2, 3, 4, 5, 6, 7, 8}),
            Frame::standard(0x203, {1})});
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.packets.empty());
  EXPECT_EQ(r.relay.counters().dropped_fragments, 4u);
  EXPECT_EQ(r.relay.counters().receiver_aborts, 0u);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 3, 0)}));
  r.outcome(id, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::complete, 3, 4)}));
}

TEST(RpdopRelay, NoOutcomeWithinOutcomeTimeoutIsAnswered0x83) {
  RelayRig r({.window = 4, .outcome_timeout = 500ms});
  r.frames(fragments(3, 1, counting(20)));
  const auto id = r.only_packet().request_id;
  EXPECT_EQ(r.relay.next_deadline(), t0 + 500ms);
  r.at(499ms);
  EXPECT_TRUE(r.out.frames.empty());
  r.at(500ms);  // the deadline itself has passed
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::timeout, 3, 4)}));
  EXPECT_EQ(r.relay.counters().outcome_timeouts, 1u);
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
  r.outcome(id, AckStatus::complete);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().stale_outcomes, 1u);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::timeout, 3, 4)}));
}

TEST(RpdopRelay, AFrameOfTheNodeAppliesItsOutcomeTimeoutFirst) {
  RelayRig r({.window = 4, .outcome_timeout = 500ms}, {3, 4});
  r.frames(fragments(3, 1, counting(20)));
  r.frames(fragments(4, 1, counting(20)));
  r.now = t0 + 600ms;
  // A frame of node 4 applies node 4's timeouts only.
  EXPECT_EQ(r.request(4),
            (Frames{ack(4, 1, AckStatus::timeout, 3, 4), ack(4, 1, AckStatus::timeout, 3, 4)}));
  EXPECT_EQ(r.relay.counters().outcome_timeouts, 1u);
  EXPECT_EQ(r.relay.next_deadline(), t0 + 500ms);
  r.frames(fragments(3, 2, counting(1)));
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::timeout, 3, 4)}));
  EXPECT_EQ(r.only_packet().rpdo, 2u);
}

TEST(RpdopRelay, FailForwardedEndsTheForwardedPacketsOfANodeOrOfAll) {
  RelayRig r({.window = 4}, {3, 5, 7});
  r.frames(fragments(3, 1, counting(20)));
  r.frames(fragments(3, 4, counting(8)));
  r.frames(fragments(5, 2, counting(17)));
  const Frames node7 = fragments(7, 1, counting(40));
  r.frames({node7[0], node7[1]});
  r.clear();
  r.relay.fail_forwarded(3, AckStatus::out_of_memory, r.out);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::out_of_memory, 3, 4),
                                  ack(3, 4, AckStatus::out_of_memory, 1, 4)}));
  EXPECT_EQ(r.relay.counters().failed, 2u);
  r.clear();
  r.relay.fail_forwarded(0, AckStatus::out_of_memory, r.out);
  EXPECT_EQ(r.out.frames, (Frames{ack(5, 2, AckStatus::out_of_memory, 3, 4)}));
  r.clear();
  r.relay.fail_forwarded(0, AckStatus::complete, r.out);  // nothing forwarded any more
  r.relay.fail_forwarded(32, AckStatus::out_of_memory, r.out);
  EXPECT_TRUE(r.out.frames.empty());
  // A packet being received is not forwarded: untouched.
  EXPECT_EQ(r.request(7), (Frames{ack(7, 1, AckStatus::in_progress, 2, 4)}));
}

// ---- Receiver aborts and resynchronisation (as a node) ------------------------------------------

TEST(RpdopRelay, WorkedExampleToggleErrorThenResynchronisationByTheAbortFrame) {
  RelayRig r({.window = 4});
  const Frames fs = fragments(3, 1, counting(40));
  EXPECT_TRUE(r.frame(fs[0]));
  EXPECT_TRUE(r.frame(fs[0]));  // repeated where t = 1 is expected
  EXPECT_EQ(r.out.frames, (Frames{Frame::standard(0x683, {0x01, 0x80, 0x01, 0x00, 0x04})}));
  r.frames({fs[1], fs[2], fs[3]});
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().dropped_fragments, 3u);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::toggle_error, 1, 4)}));
  EXPECT_TRUE(r.frame(abort_of(3, 1)));
  EXPECT_EQ(r.out.frames, (Frames{Frame::standard(0x683, {0x01, 0x85, 0x01, 0x00, 0x04})}));
  r.frames(fs);
  EXPECT_EQ(r.only_packet().bytes, counting(40));
  EXPECT_EQ(r.relay.counters().receiver_aborts, 1u);
  EXPECT_EQ(r.relay.counters().packets, 1u);
}

TEST(RpdopRelay, ResynchronisationEndsAtTheNextFinalFragment) {
  RelayRig r({.window = 4});
  const Frames fs = fragments(3, 1, counting(20));
  r.frames({fs[1]});  // t = 1 with nothing open: a lost first fragment
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::toggle_error, 0, 4)}));
  r.frames({fs[2]});  // the c = 0 fragment closes the broken packet, silently
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.packets.empty());
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::toggle_error, 0, 4)}));
  r.frames(fs);
  EXPECT_EQ(r.only_packet().bytes, counting(20));
  // An offending frame with c = 0 is its own end mark: ready at once.
  r.outcome(r.only_packet().request_id, AckStatus::complete);
  r.frames({fragment_frame(3, 1, true, false, {1})});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::toggle_error, 0, 4)}));
  r.frames(fragments(3, 1, counting(3)));
  EXPECT_EQ(r.only_packet().bytes, counting(3));
}

TEST(RpdopRelay, OversizeAbortsWithTheFragmentsBeforeIt) {
  {
    RelayRig r({.max_packet_bytes = 16, .window = 4});
    r.frames(fragments(3, 1, counting(20)));  // the third fragment (c = 0) passes 16 bytes
    EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::oversize, 2, 4)}));
    EXPECT_TRUE(r.out.packets.empty());
    r.frames(fragments(3, 1, counting(16)));  // it closed the packet itself
    EXPECT_EQ(r.only_packet().bytes, counting(16));
  }
  {
    RelayRig r({.max_packet_bytes = 12, .window = 4});
    r.frames(fragments(3, 1, counting(20)));  // the second fragment (c = 1) passes 12 bytes
    EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::oversize, 1, 4)}));
    EXPECT_EQ(r.relay.counters().dropped_fragments, 1u);  // the third, which closes it
    EXPECT_TRUE(r.out.packets.empty());
  }
  {
    RelayRig r({.max_packet_bytes = 4, .window = 4});
    r.frames({Frame::standard(0x203, {1, 2, 3, 4, 5})});  // a one-frame packet too large
    EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::oversize, 0, 4)}));
    EXPECT_EQ(r.relay.counters().receiver_aborts, 1u);
  }
}

TEST(RpdopRelay, ShortFragmentAborts0x84) {
  RelayRig r({.window = 4});
  const Frames fs = fragments(3, 1, counting(20));
  r.frames({fs[0], fragment_frame(3, 1, true, true, {1, 2, 3, 4, 5})});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::short_fragment, 1, 4)}));
  r.frames({abort_of(3, 1)});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::sender_abort, 1, 4)}));
  // A zero-length data frame with c = 1 is a short fragment, not an abort.
  r.frames({fragment_frame(3, 1, false, true, {})});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::short_fragment, 0, 4)}));
  EXPECT_EQ(r.relay.counters().receiver_aborts, 2u);
  EXPECT_EQ(r.relay.counters().sender_aborts, 1u);
}

TEST(RpdopRelay, FragmentTimeoutIsSilentAndAnswered0x83OnRequest) {
  RelayRig r({.fragment_timeout = 200ms, .window = 4});
  const Frames fs = fragments(3, 1, counting(40));
  r.frames({fs[0], fs[1]});
  EXPECT_EQ(r.relay.next_deadline(), t0 + 200ms);
  r.at(199ms);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 2, 4)}));
  r.at(200ms);
  EXPECT_TRUE(r.out.frames.empty()) << "a fragment timeout sends nothing by itself";
  EXPECT_EQ(r.relay.counters().receiver_aborts, 1u);
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::timeout, 2, 4)}));
  // The rest of the broken packet is dropped up to its final fragment.
  r.frames({fs[2], fs[3], fs[4]});
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_TRUE(r.out.packets.empty());
  EXPECT_EQ(r.relay.counters().dropped_fragments, 3u);
  r.frames(fs);
  EXPECT_EQ(r.only_packet().bytes, counting(40));
}

TEST(RpdopRelay, AFragmentAtTheDeadlineIsLateWithoutATick) {
  RelayRig r({.fragment_timeout = 200ms, .window = 4});
  const Frames fs = fragments(3, 1, counting(20));
  r.frames({fs[0]});
  r.now = t0 + 200ms;
  r.frames({fs[1]});
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().dropped_fragments, 1u);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::timeout, 1, 4)}));
}

TEST(RpdopRelay, RequestsAnswerEveryOpenPacketInRpdoOrderElseTheLastFinishedElseNothing) {
  RelayRig r({.window = 4});
  EXPECT_TRUE(r.request(3).empty()) << "nothing finished since the start";
  EXPECT_EQ(r.relay.counters().ack_requests, 1u);
  r.frames({fragments(3, 4, counting(20))[0]});                            // RPDO4: receiving
  r.frames(fragments(3, 2, counting(9)));                                  // RPDO2: forwarded
  r.frames({fragment_frame(3, 3, true, true, {1, 2, 3, 4, 5, 6, 7, 8})});  // RPDO3: aborted
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 3, AckStatus::toggle_error, 0, 4)}));
  EXPECT_EQ(r.request(3), (Frames{ack(3, 2, AckStatus::in_progress, 2, 0),
                                  ack(3, 3, AckStatus::toggle_error, 0, 4),
                                  ack(3, 4, AckStatus::in_progress, 1, 4)}));
  r.outcome(1, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 2, AckStatus::complete, 2, 4)}));
  r.frames({abort_of(3, 3), abort_of(3, 4)});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 3, AckStatus::sender_abort, 0, 4),
                                  ack(3, 4, AckStatus::sender_abort, 1, 4)}));
  // Nothing open: the packet finished last on any RPDO.
  EXPECT_EQ(r.request(3), (Frames{ack(3, 4, AckStatus::sender_abort, 1, 4)}));
  // A sender abort with nothing open is confirmed with received = 0.
  r.frames({abort_of(3, 1)});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::sender_abort, 0, 4)}));
  EXPECT_EQ(r.relay.counters().sender_aborts, 3u);
}

TEST(RpdopRelay, AnAnsweredRequestRestartsTheWindowCount) {
  RelayRig r({.window = 3});
  const Frames fs = fragments(3, 1, counting(80));
  r.frames({fs[0], fs[1]});
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.request(3), (Frames{ack(3, 1, AckStatus::in_progress, 2, 3)}));
  r.frames({fs[2], fs[3]});
  EXPECT_TRUE(r.out.frames.empty()) << "the answer counts as an acknowledgement";
  r.frames({fs[4]});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::in_progress, 5, 3)}));
  r.frames({fs[5], fs[6], fs[7], fs[8]});
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::in_progress, 8, 3)}));
  r.frames({fs[9]});  // the last draws no acknowledgement but the outcome's
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.only_packet().bytes, counting(80));
}

TEST(RpdopRelay, NextDeadlineIsTheEarliestFragmentOrOutcomeTimeout) {
  RelayRig r({.fragment_timeout = 200ms, .window = 4, .outcome_timeout = 100ms}, {3, 9});
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
  r.frames({fragments(3, 1, counting(20))[0]});
  EXPECT_EQ(r.relay.next_deadline(), t0 + 200ms);
  r.now = t0 + 50ms;
  r.frames(fragments(9, 2, counting(4)));
  EXPECT_EQ(r.relay.next_deadline(), t0 + 150ms);
  r.at(150ms);
  EXPECT_EQ(r.out.frames, (Frames{ack(9, 2, AckStatus::timeout, 1, 4)}));
  EXPECT_EQ(r.relay.next_deadline(), t0 + 200ms);
  r.at(200ms);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
}

TEST(RpdopRelay, FramesOfNodesNotRelayedAndForeignFramesAreNotTaken) {
  RelayRig r({.window = 4}, {});
  EXPECT_FALSE(r.relay.relayed(3));
  EXPECT_FALSE(r.frame(Frame::standard(0x203, {1})));
  EXPECT_FALSE(r.frame(pdop::ack_request(3)));
  EXPECT_FALSE(r.frame(abort_of(3, 1)));
  r.relay.set_relayed(3, true);
  r.relay.set_relayed(0, true);
  r.relay.set_relayed(32, true);
  EXPECT_TRUE(r.relay.relayed(3));
  EXPECT_FALSE(r.relay.relayed(0));
  EXPECT_FALSE(r.relay.relayed(32));
  EXPECT_FALSE(r.relay.relayed(4));
  const Frames foreign = {
      Frame::standard(0x183, {1, 2}),                      // TPDO1 of node 3
      Frame::standard(0x1A3, {1, 2, 3, 4, 5, 6, 7, 8}),    // a TPDOP fragment
      ack(3, 1, AckStatus::complete, 1, 4),                // an acknowledgement (data)
      Frame::make(0x203, can::FrameFlags::remote, {}),     // remote frame on the RPDO
      Frame::make(0x203, can::FrameFlags::extended, {1}),  // 29-bit identifier
      Frame::make(0x203, can::FrameFlags::error, {}),      // error frame
      Frame::standard(0x200, {1}),                         // node 0
      Frame::standard(0x204, {1}),                         // node 4, not relayed
      pdop::ack_request(4),                                // node 4, not relayed
      Frame::make(0x680, can::FrameFlags::remote, {}),     // node 0
      Frame::make(0x6A3, can::FrameFlags::remote, {}),     // beyond 0x69F
      Frame::standard(0x603, {0x40, 0x00, 0x10, 0x00}),    // SDO request
      Frame::standard(0x703, {0x05}),                      // heartbeat
      Frame::standard(0x000, {0x01, 0x03}),                // NMT
  };
  for (const Frame& f : foreign) {
    EXPECT_FALSE(r.frame(f)) << can::to_string(f);
    EXPECT_TRUE(r.out.frames.empty());
    EXPECT_TRUE(r.out.packets.empty());
  }
  EXPECT_EQ(r.relay.counters().ack_requests, 0u);
  EXPECT_EQ(r.relay.counters().receiver_aborts, 0u);
  // A remote frame of any DLC asks.
  Frame zero_dlc = Frame::make(0x683, can::FrameFlags::remote, {});
  EXPECT_TRUE(r.frame(zero_dlc));
  EXPECT_EQ(r.relay.counters().ack_requests, 1u);
}

TEST(RpdopRelay, TurningANodeOffForgetsItsStreamsSilently) {
  RelayRig r({.window = 4}, {3});
  r.frames(fragments(3, 3, counting(3)));
  r.outcome(r.only_packet().request_id, AckStatus::complete);  // a last finished packet
  r.frames(fragments(3, 1, counting(20)));                     // forwarded
  const auto id = r.only_packet().request_id;
  const Frames fs = fragments(3, 2, counting(20));
  r.frames({fs[0]});  // receiving
  r.clear();
  r.relay.set_relayed(3, false);
  EXPECT_FALSE(r.relay.relayed(3));
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
  EXPECT_FALSE(r.frame(fs[1]));
  EXPECT_FALSE(r.frame(pdop::ack_request(3)));
  r.outcome(id, AckStatus::complete);
  EXPECT_TRUE(r.out.frames.empty());
  EXPECT_EQ(r.relay.counters().stale_outcomes, 1u);

  r.relay.set_relayed(3, true);
  EXPECT_TRUE(r.request(3).empty()) << "the last finished packet is forgotten too";
  r.frames({fs[1]});  // the stream starts over: t = 1 with nothing open
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 2, AckStatus::toggle_error, 0, 4)}));
  // Turning a relayed node on again changes nothing.
  r.relay.set_relayed(3, true);
  EXPECT_EQ(r.request(3), (Frames{ack(3, 2, AckStatus::toggle_error, 0, 4)}));
}

TEST(RpdopRelay, SeveralNodesAndRpdosInterleave) {
  RelayRig r({.window = 2}, {1, 31});
  const Frames a = fragments(1, 1, counting(24));        // 3 fragments
  const Frames b = fragments(1, 4, counting(17, 100));   // 3
  const Frames c = fragments(31, 1, counting(16, 200));  // 2
  const Frames d = fragments(31, 3, counting(5, 50));    // 1
  r.frames({a[0], b[0], c[0], a[1], d[0], b[1], c[1], a[2], b[2]});
  EXPECT_EQ(r.out.frames, (Frames{ack(1, 1, AckStatus::in_progress, 2, 2),
                                  ack(1, 4, AckStatus::in_progress, 2, 2)}));
  ASSERT_EQ(r.out.packets.size(), 4u);
  const auto& p = r.out.packets;
  EXPECT_EQ(std::tuple(p[0].request_id, p[0].node, p[0].rpdo, p[0].bytes),
            std::tuple(1u, NodeId{31}, 3u, counting(5, 50)));
  EXPECT_EQ(std::tuple(p[1].request_id, p[1].node, p[1].rpdo, p[1].bytes),
            std::tuple(2u, NodeId{31}, 1u, counting(16, 200)));
  EXPECT_EQ(std::tuple(p[2].request_id, p[2].node, p[2].rpdo, p[2].bytes),
            std::tuple(3u, NodeId{1}, 1u, counting(24)));
  EXPECT_EQ(std::tuple(p[3].request_id, p[3].node, p[3].rpdo, p[3].bytes),
            std::tuple(4u, NodeId{1}, 4u, counting(17, 100)));
  // Outcomes in any order, each to its own stream.
  r.outcome(3, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(1, 1, AckStatus::complete, 3, 2)}));
  r.outcome(1, AckStatus::short_fragment);
  EXPECT_EQ(r.out.frames, (Frames{ack(31, 3, AckStatus::short_fragment, 1, 2)}));
  EXPECT_EQ(r.request(1), (Frames{ack(1, 4, AckStatus::in_progress, 3, 0)}));
  EXPECT_EQ(r.request(31), (Frames{ack(31, 1, AckStatus::in_progress, 2, 0)}));
  r.outcome(4, AckStatus::complete);
  r.outcome(2, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(31, 1, AckStatus::complete, 2, 2)}));
  EXPECT_EQ(r.relay.counters().completed, 3u);
  EXPECT_EQ(r.relay.counters().failed, 1u);
  EXPECT_EQ(r.relay.next_deadline(), std::nullopt);
}

TEST(RpdopRelay, LargestPacketAndBufferReuse) {
  RelayRig r({.max_packet_bytes = pdop::kMaxPacketBytes, .window = 255});
  Bytes big(pdop::kMaxPacketBytes);
  for (std::size_t i = 0; i < big.size(); ++i) big[i] = static_cast<std::uint8_t>(i * 7 + i / 256);
  r.frames(fragments(3, 1, big));
  EXPECT_EQ(r.out.frames.size(), 65534u / 255u);  // every window, the last fragment excepted
  EXPECT_EQ(r.only_packet().bytes, big);
  r.outcome(1, AckStatus::complete);
  EXPECT_EQ(r.out.frames, (Frames{ack(3, 1, AckStatus::complete, 65535, 255)}));
}

TEST(RpdopRelay, DefaultsAndOptionsAreValidatedWithEveryProblemNamed) {
  const RpdopRelayOptions defaults;
  EXPECT_EQ(defaults.max_packet_bytes, 4096u);
  EXPECT_EQ(defaults.fragment_timeout, 200ms);
  EXPECT_EQ(defaults.window, 4);
  EXPECT_EQ(defaults.outcome_timeout, 10s);
  EXPECT_TRUE(validate(defaults).empty());
  EXPECT_TRUE(
      validate(
          {.max_packet_bytes = 1, .fragment_timeout = 1ms, .window = 1, .outcome_timeout = 1ms})
          .empty());
  EXPECT_TRUE(validate({.max_packet_bytes = 524280,
                        .fragment_timeout = 10s,
                        .window = 255,
                        .outcome_timeout = 600s})
                  .empty());
  EXPECT_EQ(
      validate(
          {.max_packet_bytes = 0, .fragment_timeout = 0ms, .window = 0, .outcome_timeout = 0ms}),
      (std::vector<std::string>{"max_packet_bytes: 0 is outside 1..524280",
                                "fragment_timeout: 0 ms is outside 1 ms..10 s",
                                "window: 0 is outside 1..255",
                                "outcome_timeout: 0 ms is outside 1 ms..600 s"}));
  EXPECT_EQ(
      validate(
          {.max_packet_bytes = 524281, .fragment_timeout = 10001ms, .outcome_timeout = 600001ms}),
      (std::vector<std::string>{"max_packet_bytes: 524281 is outside 1..524280",
                                "fragment_timeout: 10001 ms is outside 1 ms..10 s",
                                "outcome_timeout: 600001 ms is outside 1 ms..600 s"}));
  try {
    RpdopRelay relay({.fragment_timeout = 0ms, .window = 0});
    ADD_FAILURE() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_EQ(std::string(e.what()), "RPDOP relay: fragment_timeout: 0 ms is outside 1 ms..10 s");
  }
}

// ---- End to end: the gateway's real sender as the master ----------------------------------------

// What the test, playing the gateway, answers for a forwarded packet: after `delay`, `status`.
struct Plan {
  Duration delay{0};
  AckStatus status = AckStatus::complete;
};

struct EndToEndTotals {
  std::uint64_t submitted = 0;
  std::uint64_t complete = 0;
  std::uint64_t aborted = 0;
  std::uint64_t timeouts = 0;
  std::uint64_t requests = 0;      // remote frames the segmenter sent
  std::uint64_t wait_answers = 0;  // {in progress, all, credit 0} the relay sent
  std::uint64_t one_frame = 0;
};

// A PdopSegmenter and a RpdopRelay joined by a direct channel (every frame arrives at the instant
// it is sent, in order), simulated time driven by both next_deadline()s, the submits and the
// test's outcomes.
class DirectRun {
 public:
  struct Request {
    NodeId node = 0;
    unsigned rpdo = 0;
    Bytes bytes;
    int delivered = 0;
    std::optional<AckStatus> planned;  // set when the relay forwards it
    std::optional<PdopOutcome> outcome;
  };

  DirectRun(PdopSegmenterOptions seg_options, RpdopRelayOptions relay_options,
            std::vector<NodeId> nodes)
      : seg_(seg_options), relay_(relay_options), nodes_(std::move(nodes)) {
    for (NodeId n : nodes_) relay_.set_relayed(n, true);
  }

  void submit_at(TimePoint at, NodeId node, unsigned rpdo, Bytes bytes) {
    const std::uint64_t id = ++last_id_;
    Request& r = requests_[id];
    r.node = node;
    r.rpdo = rpdo;
    r.bytes = bytes;
    submits_.emplace(at, std::pair{id, std::move(bytes)});
  }
  // Decides each forwarded packet's outcome.
  void set_planner(std::function<Plan(const RpdopRelay::Packet&)> planner) {
    planner_ = std::move(planner);
  }

  void run() {
    for (int steps = 0;; ++steps) {
      ASSERT_LT(steps, 1'000'000) << "no progress";
      std::optional<TimePoint> next;
      const auto consider = [&](std::optional<TimePoint> t) {
        if (t && (!next || *t < *next)) next = t;
      };
      if (!submits_.empty()) consider(submits_.begin()->first);
      if (!outcomes_.empty()) consider(outcomes_.begin()->first);
      consider(seg_.next_deadline());
      consider(relay_.next_deadline());
      if (!next) break;
      now_ = std::max(now_, *next);
      while (!submits_.empty() && submits_.begin()->first <= now_) {
        auto [id, bytes] = std::move(submits_.begin()->second);
        submits_.erase(submits_.begin());
        const Request& r = requests_.at(id);
        PdopSegmenter::Output out;
        seg_.submit(r.node, r.rpdo, std::move(bytes), id, now_, out);
        take(out);
        drain();
      }
      while (!outcomes_.empty() && outcomes_.begin()->first <= now_) {
        const auto [relay_id, status] = outcomes_.begin()->second;
        outcomes_.erase(outcomes_.begin());
        RpdopRelay::Output out;
        relay_.on_outcome(relay_id, status, out);
        take(out);
        drain();
      }
      PdopSegmenter::Output seg_out;
      seg_.tick(now_, seg_out);
      take(seg_out);
      drain();
      RpdopRelay::Output relay_out;
      relay_.tick(now_, relay_out);
      take(relay_out);
      drain();
      if (::testing::Test::HasFatalFailure()) return;
    }
  }

  void add_to(EndToEndTotals& totals) const {
    totals.submitted += requests_.size();
    for (const auto& [id, r] : requests_) {
      if (!r.outcome) continue;
      totals.complete += r.outcome->result == PdopResult::complete;
      totals.aborted += r.outcome->result == PdopResult::receiver_abort;
      totals.timeouts += r.outcome->result == PdopResult::timeout;
      totals.one_frame += r.bytes.size() <= pdop::kFragmentBytes;
    }
    totals.requests += seg_.counters().ack_requests;
    totals.wait_answers += wait_answers_;
  }

  // Every packet reached the relay once, bit-exact, and the segmenter reported the outcome the
  // gateway gave; both ends are idle.
  void check_delivered_exactly_once() const {
    for (const auto& [id, r] : requests_) {
      SCOPED_TRACE("request " + std::to_string(id) + " of " + std::to_string(r.bytes.size()) +
                   " bytes");
      EXPECT_EQ(r.delivered, 1);
      ASSERT_TRUE(r.outcome.has_value()) << "never ended";
      ASSERT_TRUE(r.planned.has_value());
      if (*r.planned == AckStatus::complete) {
        EXPECT_EQ(r.outcome->result, PdopResult::complete) << to_string(*r.outcome);
      } else {
        EXPECT_EQ(r.outcome->result, PdopResult::receiver_abort) << to_string(*r.outcome);
        EXPECT_EQ(r.outcome->status, *r.planned) << to_string(*r.outcome);
      }
    }
    for (NodeId n : nodes_) {
      for (unsigned rpdo = 1; rpdo <= 4; ++rpdo) {
        EXPECT_EQ(seg_.active_request(n, rpdo), std::nullopt);
      }
    }
    EXPECT_EQ(relay_.next_deadline(), std::nullopt);
    const auto& c = relay_.counters();
    EXPECT_EQ(c.packets, requests_.size());
    EXPECT_EQ(c.completed + c.failed, c.packets);
    EXPECT_EQ(c.stale_outcomes, 0u);
    EXPECT_EQ(c.outcome_timeouts, 0u);
    EXPECT_EQ(c.receiver_aborts, 0u);
    EXPECT_EQ(c.dropped_fragments, 0u);
  }

  const std::map<std::uint64_t, Request>& requests() const { return requests_; }
  const PdopSegmenter& seg() const { return seg_; }
  const RpdopRelay& relay() const { return relay_; }
  std::uint64_t wait_answers() const { return wait_answers_; }

 private:
  void take(PdopSegmenter::Output& out) {
    for (const Frame& f : out.frames) down_.push_back(f);
    for (const PdopOutcome& o : out.outcomes) {
      Request& r = requests_.at(o.request_id);
      ASSERT_FALSE(r.outcome.has_value()) << "request " << o.request_id << " ended twice";
      r.outcome = o;
    }
  }
  void take(RpdopRelay::Output& out) {
    for (const Frame& f : out.frames) {
      const auto a = pdop::decode_ack(f);
      ASSERT_TRUE(a.has_value()) << can::to_string(f);
      if (a->status == AckStatus::in_progress && a->credit == 0) ++wait_answers_;
      up_.push_back(f);
    }
    for (RpdopRelay::Packet& p : out.packets) {
      // The segmenter sent its last fragment at this instant, so it is still its active request.
      const auto active = seg_.active_request(p.node, p.rpdo);
      ASSERT_TRUE(active.has_value()) << "node " << int{p.node} << " RPDO" << p.rpdo;
      Request& r = requests_.at(*active);
      ASSERT_EQ(p.bytes, r.bytes) << "request " << *active;
      ASSERT_EQ(++r.delivered, 1) << "request " << *active << " forwarded twice";
      const Plan plan = planner_(p);
      r.planned = plan.status;
      outcomes_.emplace(now_ + plan.delay, std::pair{p.request_id, plan.status});
    }
  }
  void drain() {
    while (!down_.empty() || !up_.empty()) {
      if (!down_.empty()) {
        const Frame f = down_.front();
        down_.pop_front();
        RpdopRelay::Output out;
        ASSERT_TRUE(relay_.on_frame(f, now_, out)) << can::to_string(f);
        take(out);
      } else {
        const Frame f = up_.front();
        up_.pop_front();
        PdopSegmenter::Output out;
        ASSERT_TRUE(seg_.on_frame(f, now_, out)) << can::to_string(f);
        take(out);
      }
      if (::testing::Test::HasFatalFailure()) return;
    }
  }

  PdopSegmenter seg_;
  RpdopRelay relay_;
  std::vector<NodeId> nodes_;
  std::function<Plan(const RpdopRelay::Packet&)> planner_ = [](const RpdopRelay::Packet&) {
    return Plan{};
  };
  TimePoint now_ = t0;
  std::multimap<TimePoint, std::pair<std::uint64_t, Bytes>> submits_;
  std::multimap<TimePoint, std::pair<std::uint64_t, AckStatus>> outcomes_;
  std::deque<Frame> down_, up_;  // segmenter to relay, relay to segmenter
  std::map<std::uint64_t, Request> requests_;
  std::uint64_t last_id_ = 0;
  std::uint64_t wait_answers_ = 0;
};

TEST(RpdopRelayEndToEnd, TwentyBytesWithAnOutcomeLaterThanTheAckTimeout) {
  DirectRun run({.window = 2, .ack_timeout = 100ms, .retries = 3}, {.window = 2}, {3});
  run.submit_at(t0, 3, 1, counting(20));
  run.set_planner([](const RpdopRelay::Packet&) { return Plan{250ms, AckStatus::complete}; });
  run.run();
  run.check_delivered_exactly_once();
  const auto& o = run.requests().at(1).outcome;
  ASSERT_TRUE(o.has_value());
  EXPECT_EQ(o->result, PdopResult::complete);
  EXPECT_EQ(o->elapsed, 250ms);
  EXPECT_EQ(o->ack_requests, 2u);  // at 100 and 200 ms, each answered "wait"
  EXPECT_EQ(run.wait_answers(), 2u);
  EXPECT_EQ(run.relay().counters().ack_requests, 2u);
  EXPECT_EQ(o->retransmissions, 0u);
}

TEST(RpdopRelayEndToEnd, AnAbortOutcomeReachesTheSegmenterAsReceiverAbort) {
  DirectRun run({.window = 4, .ack_timeout = 50ms}, {.window = 4}, {31});
  run.submit_at(t0, 31, 4, counting(100));
  run.submit_at(t0 + 1ms, 31, 4, counting(7));
  int n = 0;
  run.set_planner([&n](const RpdopRelay::Packet&) {
    return ++n == 1 ? Plan{120ms, AckStatus::out_of_memory} : Plan{10ms, AckStatus::complete};
  });
  run.run();
  run.check_delivered_exactly_once();
  const auto& first = run.requests().at(1).outcome;
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->result, PdopResult::receiver_abort);
  EXPECT_EQ(first->status, AckStatus::out_of_memory);
  // The segmenter aborts after a receiver abort; the relay confirms and takes the next packet.
  EXPECT_EQ(run.relay().counters().sender_aborts, 1u);
  EXPECT_EQ(run.requests().at(2).outcome->result, PdopResult::complete);
}

// A master may wait longer than retries x ack_timeout for the node: each request is answered.
TEST(RpdopRelayEndToEnd, AWaitLongerThanTheSegmentersRetriesEndsComplete) {
  // The relay's wait answer {0, n, 0} answers each request: the sender's retries never run out.
  DirectRun run({.window = 4, .ack_timeout = 100ms, .retries = 3}, {.window = 4}, {3});
  run.submit_at(t0, 3, 1, counting(20));
  run.set_planner([](const RpdopRelay::Packet&) { return Plan{1s, AckStatus::complete}; });
  run.run();
  const auto& r = run.requests().at(1);
  EXPECT_EQ(r.delivered, 1);
  ASSERT_TRUE(r.outcome.has_value());
  EXPECT_EQ(r.outcome->result, PdopResult::complete);
  EXPECT_EQ(r.outcome->elapsed, 1s);
  EXPECT_GE(run.wait_answers(), 9u) << "asked every 100 ms, answered every time";
  EXPECT_EQ(run.relay().counters().sender_aborts, 0u);
  EXPECT_EQ(run.relay().counters().stale_outcomes, 0u);
  EXPECT_EQ(run.relay().counters().completed, 1u);
}

// Random packets on random streams, outcomes after random delays (often longer than the
// segmenter's ack_timeout, some longer than its retries x ack_timeout), some of
// them aborts: each packet is forwarded exactly once and bit-exact, and the segmenter reports
// exactly the gateway's outcome.
TEST(RpdopRelayEndToEnd, EveryPacketIsForwardedOnceAndEndsWithTheGatewaysOutcome) {
  EndToEndTotals totals;
  const std::vector<NodeId> nodes{1, 2, 31};
  for (std::uint32_t seed = 1; seed <= 24; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937 rng(seed);
    const auto window = static_cast<std::uint8_t>(1 + seed % 5);
    const Duration ack_timeout = std::array<Duration, 3>{20ms, 50ms, 100ms}[seed % 3];
    const unsigned retries = 1 + seed % 3;
    const std::size_t max_packet = std::array<std::size_t, 3>{64, 300, 2000}[seed % 3];
    DirectRun run(
        {.max_packet_bytes = max_packet,
         .window = window,
         .ack_timeout = std::chrono::duration_cast<std::chrono::milliseconds>(ack_timeout),
         .retries = retries,
         .queue_per_rpdo = 1024},
        {.max_packet_bytes = max_packet, .window = window}, nodes);
    TimePoint at = t0;
    for (int i = 0; i < 120; ++i) {
      at += std::chrono::milliseconds(rng() % 40);
      const NodeId node = nodes[rng() % nodes.size()];
      const unsigned rpdo = 1 + rng() % 4;
      const std::size_t size =
          rng() % 4 == 0 ? 1 + rng() % pdop::kFragmentBytes : 1 + rng() % max_packet;
      Bytes bytes(size);
      for (auto& b : bytes) b = static_cast<std::uint8_t>(rng());
      run.submit_at(at, node, rpdo, std::move(bytes));
    }
    const Duration give_up = ack_timeout * (retries + 1);
    run.set_planner([&](const RpdopRelay::Packet&) {
      const auto us = [](Duration d) {
        return static_cast<std::uint64_t>(
            std::chrono::duration_cast<std::chrono::microseconds>(d).count());
      };
      Plan plan;
      // Below the ack_timeout (no request), or up to twice the time the sender would give up
      // after if the relay's wait answers did not count as answers.
      plan.delay = rng() % 3 == 0
                       ? std::chrono::microseconds(rng() % us(ack_timeout))
                       : ack_timeout + std::chrono::microseconds(rng() % (2 * us(give_up)));
      if (rng() % 5 == 0) {
        static constexpr std::uint8_t kAborts[] = {0x80, 0x81, 0x82, 0x83, 0x84, 0x86, 0xC0};
        plan.status = static_cast<AckStatus>(kAborts[rng() % std::size(kAborts)]);
      }
      return plan;
    });
    run.run();
    if (HasFatalFailure()) return;
    run.check_delivered_exactly_once();
    run.add_to(totals);
    if (HasFailure()) return;
  }
  std::cout << "submitted " << totals.submitted << ", complete " << totals.complete
            << ", aborted by the gateway " << totals.aborted << ", one-frame " << totals.one_frame
            << ", requests " << totals.requests << ", wait answers " << totals.wait_answers << "\n";
  // Not vacuous: every path was taken.
  EXPECT_EQ(totals.complete + totals.aborted, totals.submitted);
  EXPECT_EQ(totals.timeouts, 0u);
  EXPECT_GT(totals.aborted, 0u);
  EXPECT_GT(totals.one_frame, 0u);
  EXPECT_GT(totals.wait_answers, totals.submitted / 4);
}

}  // namespace
}  // namespace canbridge::bridge
