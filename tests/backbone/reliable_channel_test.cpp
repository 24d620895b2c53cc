#include "backbone/reliable_channel.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <deque>
#include <iostream>
#include <optional>
#include <ostream>
#include <random>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;
using TimePoint = ReliableSender::TimePoint;
using Verdict = ReliableReceiver::Verdict;

constexpr auto kRto = 100ms;
const TimePoint kT0 = TimePoint{} + 1h;  // away from the epoch, which the sender uses as "never"

// A sender whose link is up, as after a hello exchange.
ReliableSender connected_sender(std::size_t max_messages = 100, std::size_t max_bytes = 10000) {
  ReliableSender sender({.max_messages = max_messages, .max_bytes = max_bytes});
  sender.on_link_up();
  return sender;
}

// "m<n>". Built by appending: GCC 12 at -O3 warns falsely (-Wrestrict) on "m" + std::string.
std::string numbered(std::uint64_t n) {
  std::string text = "m";
  text += std::to_string(n);
  return text;
}

// Hands out everything unsent; returns the seqs in hand-out order.
std::vector<std::uint64_t> send_all(ReliableSender& sender, TimePoint now) {
  std::vector<std::uint64_t> seqs;
  while (auto out = sender.next_to_send(now)) seqs.push_back(out->seq);
  return seqs;
}

// ---------------------------------------------------------------------------------------------
// ReliableSender

TEST(ReliableSender, RejectsZeroBounds) {
  EXPECT_THROW(ReliableSender({.max_messages = 0, .max_bytes = 10}), std::invalid_argument);
  EXPECT_THROW(ReliableSender({.max_messages = 10, .max_bytes = 0}), std::invalid_argument);
}

TEST(ReliableSender, PushAssignsConsecutiveSeqsStartingAtOne) {
  ReliableSender sender({.max_messages = 10, .max_bytes = 100});
  EXPECT_EQ(sender.send_base(), 1u);
  EXPECT_EQ(sender.next_seq(), 1u);
  EXPECT_EQ(sender.push("a"), 1u);
  EXPECT_EQ(sender.push("bb"), 2u);
  EXPECT_EQ(sender.push("ccc"), 3u);
  EXPECT_EQ(sender.next_seq(), 4u);
  EXPECT_EQ(sender.send_base(), 1u);
  EXPECT_EQ(sender.unacked_count(), 3u);
  EXPECT_EQ(sender.unacked_bytes(), 6u);
  EXPECT_EQ(sender.counters().pushed, 3u);
}

TEST(ReliableSender, SendsNothingWhileTheLinkIsDown) {
  ReliableSender sender({.max_messages = 10, .max_bytes = 100});
  ASSERT_TRUE(sender.push("a"));
  EXPECT_FALSE(sender.link_up());
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_FALSE(sender.next_to_send(kT0));
  sender.on_link_up();
  EXPECT_TRUE(sender.has_unsent());
  EXPECT_TRUE(sender.next_to_send(kT0));
  ASSERT_TRUE(sender.push("b"));
  sender.on_link_down();
  EXPECT_FALSE(sender.next_to_send(kT0));
  EXPECT_EQ(sender.counters().sent, 1u);
}

TEST(ReliableSender, HandsOutInSeqOrderWithPayloadsAsFirstTransmissions) {
  ReliableSender sender = connected_sender();
  ASSERT_TRUE(sender.push("one"));
  ASSERT_TRUE(sender.push("two"));
  auto first = sender.next_to_send(kT0);
  ASSERT_TRUE(first);
  EXPECT_EQ(first->seq, 1u);
  EXPECT_EQ(first->payload, "one");
  EXPECT_FALSE(first->retransmission);
  ASSERT_TRUE(sender.push("three"));  // pushed while earlier ones are in flight
  auto second = sender.next_to_send(kT0);
  ASSERT_TRUE(second);
  EXPECT_EQ(second->seq, 2u);
  EXPECT_EQ(second->payload, "two");
  auto third = sender.next_to_send(kT0);
  ASSERT_TRUE(third);
  EXPECT_EQ(third->seq, 3u);
  EXPECT_EQ(third->payload, "three");
  EXPECT_FALSE(sender.next_to_send(kT0));
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_EQ(sender.counters().sent, 3u);
  EXPECT_EQ(sender.counters().retransmitted, 0u);
}

TEST(ReliableSender, CumulativeAckReleasesEverythingUpToIt) {
  ReliableSender sender = connected_sender();
  for (const char* payload : {"a", "bb", "ccc", "dddd"}) ASSERT_TRUE(sender.push(payload));
  send_all(sender, kT0);
  sender.on_ack(2, kT0);
  EXPECT_EQ(sender.send_base(), 3u);
  EXPECT_EQ(sender.unacked_count(), 2u);
  EXPECT_EQ(sender.unacked_bytes(), 7u);
  EXPECT_EQ(sender.counters().acked, 2u);
  sender.on_ack(4, kT0);
  EXPECT_EQ(sender.send_base(), 5u);
  EXPECT_EQ(sender.unacked_count(), 0u);
  EXPECT_EQ(sender.unacked_bytes(), 0u);
  EXPECT_EQ(sender.counters().acked, 4u);
  sender.rewind();  // nothing left to resend
  EXPECT_FALSE(sender.next_to_send(kT0));
}

TEST(ReliableSender, EditedUnackedPayloadsAreWhatGoesAgainWithTheirSeqs) {
  ReliableSender sender = connected_sender();
  for (const char* payload : {"a", "bb", "ccc"}) ASSERT_TRUE(sender.push(payload));
  send_all(sender, kT0);
  sender.on_ack(1, kT0);  // "a" is acknowledged: never edited again
  std::vector<std::string> seen;
  sender.edit_unacked([&](std::string& p) {
    seen.push_back(p);
    p.resize(p.size() - 1);
  });
  EXPECT_EQ(seen, (std::vector<std::string>{"bb", "ccc"}));
  EXPECT_EQ(sender.unacked_bytes(), 3u);
  sender.on_link_down();
  sender.on_link_up();
  auto first = sender.next_to_send(kT0);
  ASSERT_TRUE(first);
  EXPECT_EQ(first->seq, 2u);
  EXPECT_EQ(first->payload, "b");
  auto second = sender.next_to_send(kT0);
  ASSERT_TRUE(second);
  EXPECT_EQ(second->seq, 3u);
  EXPECT_EQ(second->payload, "cc");
}

TEST(ReliableSender, StaleDuplicatedAndReorderedAcksAreIgnored) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.on_ack(3, kT0);
  sender.on_ack(3, kT0);  // duplicated
  sender.on_ack(1, kT0);  // overtaken by a later one
  sender.on_ack(0, kT0);  // "nothing received yet"
  EXPECT_EQ(sender.send_base(), 4u);
  EXPECT_EQ(sender.unacked_count(), 2u);
  EXPECT_EQ(sender.counters().acked, 3u);
  EXPECT_EQ(sender.counters().bogus_acks, 0u);
  sender.on_ack(5, kT0);
  sender.on_ack(4, kT0);
  EXPECT_EQ(sender.send_base(), 6u);
  EXPECT_EQ(sender.counters().acked, 5u);
}

TEST(ReliableSender, AckAboveTheHighestSeqEverSentIsBogusAndIgnored) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  sender.on_ack(1, kT0);  // nothing sent yet
  EXPECT_EQ(sender.counters().bogus_acks, 1u);
  ASSERT_TRUE(sender.next_to_send(kT0));
  ASSERT_TRUE(sender.next_to_send(kT0));
  sender.on_ack(3, kT0);  // pushed but never sent
  sender.on_ack(1000, kT0);
  EXPECT_EQ(sender.counters().bogus_acks, 3u);
  EXPECT_EQ(sender.send_base(), 1u);
  EXPECT_EQ(sender.unacked_count(), 4u);
  EXPECT_EQ(sender.counters().acked, 0u);
  sender.on_ack(2, kT0);  // the highest sent is fine
  EXPECT_EQ(sender.send_base(), 3u);
  EXPECT_EQ(sender.counters().bogus_acks, 3u);
}

TEST(ReliableSender, RewindResendsFromOldestUnackedThenContinuesWithNew) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push(numbered(i + 1)));
  ASSERT_EQ(send_all(sender, kT0).size(), 5u);
  sender.on_ack(2, kT0);
  ASSERT_TRUE(sender.push("m6"));
  sender.rewind();
  std::vector<std::pair<std::uint64_t, bool>> handed_out;
  while (auto out = sender.next_to_send(kT0)) {
    EXPECT_EQ(out->payload, numbered(out->seq));
    handed_out.emplace_back(out->seq, out->retransmission);
  }
  const std::vector<std::pair<std::uint64_t, bool>> expected{
      {3, true}, {4, true}, {5, true}, {6, false}};
  EXPECT_EQ(handed_out, expected);
  EXPECT_EQ(sender.counters().sent, 9u);
  EXPECT_EQ(sender.counters().retransmitted, 3u);
}

TEST(ReliableSender, AckDuringARewindSkipsWhatItReleased) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.rewind();
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  sender.on_ack(3, kT0);
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{4, 5}));
}

TEST(ReliableSender, LinkCutResendsEveryUnackedMessageOnTheNextLink) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 2u);
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 3u);
  sender.on_ack(1, kT0);
  sender.on_link_down();
  EXPECT_FALSE(sender.has_unsent());
  sender.on_link_up();
  sender.on_ack(1, kT0);  // the peer's hello
  sender.rewind();
  std::vector<bool> retransmission;
  std::vector<std::uint64_t> seqs;
  while (auto out = sender.next_to_send(kT0)) {
    seqs.push_back(out->seq);
    retransmission.push_back(out->retransmission);
  }
  EXPECT_EQ(seqs, (std::vector<std::uint64_t>{2, 3, 4}));
  EXPECT_EQ(retransmission, (std::vector<bool>{true, true, false}));
}

TEST(ReliableSender, NewLinkStartsAtTheOldestUnackedEvenWithoutRewind) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.on_link_down();
  sender.on_link_up();
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{1, 2, 3}));
}

TEST(ReliableSender, HelloAckFromTheNewLinkReleasesAndRewinds) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.on_link_down();
  sender.on_link_up();
  sender.on_ack(3, kT0);  // the peer got 1..3 before the cut, but the acks were lost
  sender.rewind();
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{4}));
}

TEST(ReliableSender, ResendRequestResendsOnlyTheFirstMissingThenContinues) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push(numbered(i + 1)));
  ASSERT_EQ(send_all(sender, kT0).size(), 5u);
  ASSERT_TRUE(sender.push("m6"));
  EXPECT_TRUE(sender.on_resend_request(2, kT0, kRto));
  EXPECT_EQ(sender.send_base(), 3u);
  EXPECT_TRUE(sender.has_unsent());
  auto resent = sender.next_to_send(kT0);
  ASSERT_TRUE(resent);
  EXPECT_EQ(resent->seq, 3u);
  EXPECT_EQ(resent->payload, "m3");
  EXPECT_TRUE(resent->retransmission);
  auto fresh = sender.next_to_send(kT0);  // then where it was, not a rewind of 4 and 5
  ASSERT_TRUE(fresh);
  EXPECT_EQ(fresh->seq, 6u);
  EXPECT_FALSE(fresh->retransmission);
  EXPECT_FALSE(sender.next_to_send(kT0));
  EXPECT_EQ(sender.counters().sent, 7u);
  EXPECT_EQ(sender.counters().retransmitted, 1u);
  EXPECT_EQ(sender.counters().selective_retransmits, 1u);
}

TEST(ReliableSender, ScheduledRetransmissionGoesBeforeNewMessages) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sender.push("x"));
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 2u);
  ASSERT_TRUE(sender.on_resend_request(0, kT0, kRto));
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{1, 3}));
}

TEST(ReliableSender, AckReleasingAScheduledRetransmissionCancelsIt) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  ASSERT_TRUE(sender.on_resend_request(1, kT0, kRto));
  sender.on_ack(3, kT0);  // the original of 2 arrived after all
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_FALSE(sender.next_to_send(kT0));
  EXPECT_EQ(sender.counters().selective_retransmits, 0u);
}

TEST(ReliableSender, ResendRequestForWhatThisLinkHasNotCarriedSchedulesNothing) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 2u);
  sender.on_link_down();
  sender.on_link_up();
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  // Requests from the old link: 2 goes out in order anyway; 1 has been acked by the request.
  EXPECT_FALSE(sender.on_resend_request(1, kT0, kRto));
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{2, 3, 4}));
  EXPECT_EQ(sender.counters().selective_retransmits, 0u);
}

TEST(ReliableSender, RewindAndLinkChangesDropAScheduledRetransmission) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  ASSERT_TRUE(sender.on_resend_request(1, kT0, kRto));
  sender.rewind();  // covers 2 anyway: it must not go twice
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{2, 3}));
  ASSERT_TRUE(sender.on_resend_request(1, kT0 + kRto, kRto));
  sender.on_link_down();
  sender.on_link_up();
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{2, 3}));
}

TEST(ReliableSender, IdenticalResendRequestsAreThrottledPerInterval) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  ASSERT_TRUE(sender.on_resend_request(2, kT0, kRto));
  EXPECT_FALSE(sender.on_resend_request(2, kT0, kRto));  // already scheduled
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{3}));
  // One request per message that arrived after the gap: none of them may resend again.
  for (int i = 0; i < 5; ++i) EXPECT_FALSE(sender.on_resend_request(2, kT0 + 10ms * i, kRto));
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_FALSE(sender.on_resend_request(2, kT0 + kRto - 1ns, kRto));
  // The retransmission was lost too: after the interval the same request is honoured again.
  EXPECT_TRUE(sender.on_resend_request(2, kT0 + kRto, kRto));
  EXPECT_EQ(send_all(sender, kT0 + kRto), (std::vector<std::uint64_t>{3}));
  // A different gap is a new request, even within the interval.
  EXPECT_TRUE(sender.on_resend_request(6, kT0 + kRto + 1ms, kRto));
  EXPECT_EQ(send_all(sender, kT0 + kRto), (std::vector<std::uint64_t>{7}));
  EXPECT_EQ(sender.counters().selective_retransmits, 3u);
}

TEST(ReliableSender, StaleOrBogusResendRequestsScheduleNothing) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.on_ack(4, kT0);
  EXPECT_FALSE(sender.on_resend_request(2, kT0, kRto));  // that gap has been filled since
  EXPECT_FALSE(sender.on_resend_request(9, kT0, kRto));  // never sent
  EXPECT_EQ(sender.counters().bogus_acks, 1u);
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_EQ(sender.send_base(), 5u);
}

TEST(ReliableSender, RetransmitIsDueOnlyAfterRtoWithoutProgressOnTheCurrentLink) {
  ReliableSender sender = connected_sender();
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));  // nothing held
  ASSERT_TRUE(sender.push("a"));
  ASSERT_TRUE(sender.push("b"));
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));  // held but never sent
  ASSERT_TRUE(sender.next_to_send(kT0));
  EXPECT_FALSE(sender.retransmit_due(kT0 + kRto, kRto));
  EXPECT_TRUE(sender.retransmit_due(kT0 + kRto + 1ns, kRto));
  sender.rewind();  // due and rewound: not due again until the oldest has been resent
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));
  const TimePoint resent = kT0 + 200ms;
  ASSERT_TRUE(sender.next_to_send(resent)->retransmission);
  EXPECT_FALSE(sender.retransmit_due(resent + kRto, kRto));
  EXPECT_TRUE(sender.retransmit_due(resent + kRto + 1ns, kRto));
  sender.on_link_down();
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));
  sender.on_link_up();
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));  // not yet sent on this link
}

TEST(ReliableSender, AckProgressRestartsTheRetransmitTimer) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);  // a queue draining slowly over the link
  sender.on_ack(1, kT0 + 80ms);
  EXPECT_FALSE(sender.retransmit_due(kT0 + 150ms, kRto));
  EXPECT_TRUE(sender.retransmit_due(kT0 + 181ms, kRto));
  sender.on_ack(1, kT0 + 170ms);  // a duplicate is no progress
  EXPECT_TRUE(sender.retransmit_due(kT0 + 181ms, kRto));
}

TEST(ReliableSender, NacksScheduleFurtherHolesLowestFirstWithoutDuplicates) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 8; ++i) ASSERT_TRUE(sender.push("x"));
  ASSERT_EQ(send_all(sender, kT0).size(), 8u);
  const TimePoint later = kT0 + kRto;
  ASSERT_TRUE(sender.on_resend_request(1, later, kRto / 4));  // 2 missing, and 4 and 6
  EXPECT_TRUE(sender.on_nack(6, later, kRto / 4));
  EXPECT_TRUE(sender.on_nack(4, later, kRto / 4));
  EXPECT_FALSE(sender.on_nack(4, later, kRto / 4));  // already scheduled
  EXPECT_FALSE(sender.on_nack(1, later, kRto / 4));  // acked
  EXPECT_FALSE(sender.on_nack(9, later, kRto / 4));  // never pushed
  ASSERT_TRUE(sender.push("x"));
  EXPECT_FALSE(sender.on_nack(9, later, kRto / 4));  // not handed out on this link yet
  EXPECT_EQ(send_all(sender, later), (std::vector<std::uint64_t>{2, 4, 6, 9}));
  // Just resent: that copy may still be on its way.
  EXPECT_FALSE(sender.on_nack(4, later + kRto / 4 - 1ns, kRto / 4));
  EXPECT_TRUE(sender.on_nack(4, later + kRto / 4, kRto / 4));
  sender.on_ack(5, later);  // released: no longer resent
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_EQ(sender.counters().selective_retransmits, 3u);
}

TEST(ReliableSender, TimeoutWithoutAReportedGapRewinds) {
  // Nothing reported missing: the tail was lost, and the peer holds nothing after it.
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  sender.on_ack(1, kT0);
  ASSERT_TRUE(sender.retransmit_due(kT0 + kRto + 1ns, kRto));
  EXPECT_EQ(sender.on_retransmit_timeout(), ReliableSender::TimeoutAction::rewind);
  EXPECT_EQ(send_all(sender, kT0 + kRto), (std::vector<std::uint64_t>{2, 3, 4}));
  EXPECT_EQ(sender.counters().timeouts, 1u);
  EXPECT_EQ(sender.counters().timeout_rewinds, 1u);
}

TEST(ReliableSender, TimeoutOnAReportedGapResendsTheOldestOnlyThenRewinds) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  ASSERT_TRUE(sender.on_resend_request(1, kT0, kRto / 4));
  EXPECT_FALSE(sender.retransmit_due(kT0 + 1h, kRto));  // its resend is scheduled
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{2}));
  // That resend was lost, and so were the receiver's further requests.
  TimePoint now = kT0 + kRto + 1ns;
  ASSERT_TRUE(sender.retransmit_due(now, kRto));
  EXPECT_EQ(sender.on_retransmit_timeout(), ReliableSender::TimeoutAction::resend_oldest);
  EXPECT_FALSE(sender.retransmit_due(now, kRto));
  EXPECT_EQ(send_all(sender, now), (std::vector<std::uint64_t>{2}));
  EXPECT_FALSE(sender.retransmit_due(now + kRto, kRto));
  // No progress on the second timeout either: the peer may not hold what we assume.
  now += kRto + 1ns;
  ASSERT_TRUE(sender.retransmit_due(now, kRto));
  EXPECT_EQ(sender.on_retransmit_timeout(), ReliableSender::TimeoutAction::rewind);
  EXPECT_EQ(send_all(sender, now), (std::vector<std::uint64_t>{2, 3, 4, 5}));
  // Progress resets the count: the next reported gap gets a single resend on timeout again.
  ASSERT_TRUE(sender.on_resend_request(2, now, kRto / 4));
  send_all(sender, now);
  now += kRto + 1ns;
  ASSERT_TRUE(sender.retransmit_due(now, kRto));
  EXPECT_EQ(sender.on_retransmit_timeout(), ReliableSender::TimeoutAction::resend_oldest);
  EXPECT_EQ(send_all(sender, now), (std::vector<std::uint64_t>{3}));
  EXPECT_EQ(sender.counters().timeouts, 3u);
  EXPECT_EQ(sender.counters().timeout_rewinds, 1u);
}

TEST(ReliableSender, MessageBoundRefusesAndCountsOverflow) {
  ReliableSender sender = connected_sender(/*max_messages=*/3, /*max_bytes=*/1000);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sender.push("x"));
  EXPECT_FALSE(sender.can_accept(1));
  EXPECT_EQ(sender.counters().overflow, 0u);  // asking is not overflowing
  EXPECT_FALSE(sender.push("y"));
  EXPECT_FALSE(sender.push("y"));
  EXPECT_EQ(sender.counters().overflow, 2u);
  EXPECT_EQ(sender.next_seq(), 4u);  // refused pushes consume no seq
  send_all(sender, kT0);
  sender.on_ack(1, kT0);
  EXPECT_TRUE(sender.can_accept(1));
  EXPECT_EQ(sender.push("y"), 4u);
  EXPECT_EQ(sender.counters().pushed, 4u);
}

TEST(ReliableSender, ByteBoundRefusesAndCountsOverflow) {
  ReliableSender sender = connected_sender(/*max_messages=*/100, /*max_bytes=*/10);
  EXPECT_FALSE(sender.can_accept(11));
  EXPECT_FALSE(sender.push(std::string(11, 'x')));  // can never fit
  ASSERT_TRUE(sender.push(std::string(6, 'x')));
  EXPECT_TRUE(sender.can_accept(4));
  EXPECT_FALSE(sender.can_accept(5));
  EXPECT_FALSE(sender.push(std::string(5, 'x')));
  ASSERT_TRUE(sender.push(std::string(4, 'x')));  // exactly full
  EXPECT_EQ(sender.unacked_bytes(), 10u);
  EXPECT_TRUE(sender.can_accept(0));
  EXPECT_EQ(sender.counters().overflow, 2u);
  send_all(sender, kT0);
  sender.on_ack(1, kT0);
  EXPECT_EQ(sender.unacked_bytes(), 4u);
  EXPECT_TRUE(sender.push(std::string(6, 'x')));
}

TEST(ReliableSender, RingWrapsAroundWithoutMixingUpPayloads) {
  ReliableSender sender = connected_sender(/*max_messages=*/5, /*max_bytes=*/1000);
  std::uint64_t next_payload = 1;
  std::uint64_t next_expected = 1;
  for (int round = 0; round < 200; ++round) {
    while (sender.can_accept(8)) {
      ASSERT_EQ(sender.push(std::to_string(next_payload)), next_payload);
      ++next_payload;
    }
    // Ack a varying part, then resend the rest, so the ring's head moves by odd amounts.
    while (auto out = sender.next_to_send(kT0)) {
      ASSERT_EQ(out->payload, std::to_string(out->seq));
    }
    const std::uint64_t ack = std::min(sender.next_seq() - 1, next_expected + round % 4);
    sender.on_ack(ack, kT0);
    next_expected = ack + 1;
    sender.rewind();
    while (auto out = sender.next_to_send(kT0)) {
      ASSERT_EQ(out->payload, std::to_string(out->seq));
      ASSERT_GE(out->seq, next_expected);
    }
  }
  EXPECT_GT(sender.counters().acked, 300u);
}

// Old payloads become tombstones: emptied, their seqs kept, so a receiver waiting for them is
// not left with a hole; acks release them like any other.
TEST(ReliableSender, DropOlderThanTombstonesOnlyWhatIsOlderAndKeepsTheSequence) {
  ReliableSender sender = connected_sender();
  ASSERT_EQ(sender.push("old", kT0), 1u);
  ASSERT_EQ(sender.push("new", kT0 + 2s), 2u);
  ASSERT_EQ(sender.push("older", kT0 - 1s), 3u);
  ASSERT_EQ(sender.push("ageless"), 4u);
  std::vector<std::string> dropped;
  const auto keep = [&](const std::string& p, auto...) { dropped.push_back(p); };
  EXPECT_EQ(sender.drop_older_than(kT0 - 1s, keep), 0u);  // none is older than its birth
  EXPECT_EQ(sender.drop_older_than(kT0 + 1s, keep), 2u);
  EXPECT_EQ(dropped, (std::vector<std::string>{"old", "older"}));
  EXPECT_EQ(sender.unacked_count(), 4u);
  EXPECT_EQ(sender.unacked_bytes(), 3u + 7u);
  std::vector<std::pair<std::uint64_t, std::string>> out;
  while (auto m = sender.next_to_send(kT0)) out.emplace_back(m->seq, std::string(m->payload));
  EXPECT_EQ(out, (std::vector<std::pair<std::uint64_t, std::string>>{
                     {1, ""}, {2, "new"}, {3, ""}, {4, "ageless"}}));
  EXPECT_EQ(sender.drop_older_than(kT0 + 1s, keep), 0u);  // tombstones are not dropped twice
  EXPECT_EQ(sender.drop_all(keep), 2u);
  EXPECT_EQ(dropped.back(), "ageless");
  EXPECT_EQ(sender.unacked_bytes(), 0u);
  sender.on_ack(4, kT0);
  EXPECT_EQ(sender.unacked_count(), 0u);
}

// A tombstone of a payload already handed out stands for nothing lost when only the ack was
// late: drop_older_than says which ones were sent, so a drop counter can leave them out.
TEST(ReliableSender, DropOlderThanSaysWhichPayloadsWereSentBefore) {
  ReliableSender sender = connected_sender();
  for (int i = 1; i <= 5; ++i) ASSERT_TRUE(sender.push(std::to_string(i), kT0));
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 2u);
  sender.on_link_down();  // 3..5 never left; 1 and 2 may have arrived
  sender.on_link_up();
  ASSERT_EQ(sender.next_to_send(kT0)->seq, 1u);  // a retransmission after the new link
  std::vector<std::pair<std::string, bool>> dropped;
  EXPECT_EQ(sender.drop_older_than(
                kT0 + 1s, [&](const std::string& p, bool sent) { dropped.emplace_back(p, sent); }),
            5u);
  EXPECT_EQ(dropped, (std::vector<std::pair<std::string, bool>>{
                         {"1", true}, {"2", true}, {"3", false}, {"4", false}, {"5", false}}));
}

// ---------------------------------------------------------------------------------------------
// ReliableReceiver

// Everything the receiver hands out after a deliver verdict for `seq` with `payload`.
std::vector<std::string> deliver_and_drain(ReliableReceiver& receiver, std::uint64_t seq,
                                           std::string_view payload) {
  std::vector<std::string> delivered;
  if (receiver.accept(seq, payload) != Verdict::deliver) return delivered;
  delivered.emplace_back(payload);
  receiver.drain([&delivered](std::string&& next) { delivered.push_back(std::move(next)); });
  return delivered;
}

TEST(ReliableReceiver, DeliversInOrderAndAcksCumulatively) {
  ReliableReceiver receiver;
  EXPECT_EQ(receiver.cumulative_ack(), 0u);
  EXPECT_EQ(receiver.accept(1, "a"), Verdict::deliver);
  EXPECT_EQ(receiver.accept(2, "b"), Verdict::deliver);
  EXPECT_EQ(receiver.cumulative_ack(), 2u);
  EXPECT_EQ(receiver.expected(), 3u);
  EXPECT_EQ(receiver.first_missing(), 3u);
  EXPECT_FALSE(receiver.has_gap());
  EXPECT_FALSE(receiver.next_buffered());
  EXPECT_EQ(receiver.counters().delivered, 2u);
}

TEST(ReliableReceiver, BuffersAfterAGapAndDrainsInOrderOnceItIsFilled) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1, "m1"), Verdict::deliver);
  EXPECT_EQ(receiver.accept(3, "m3"), Verdict::buffered);  // 2 was lost
  EXPECT_EQ(receiver.accept(5, "m5"), Verdict::buffered);  // and 4
  EXPECT_EQ(receiver.accept(6, "m6"), Verdict::buffered);
  EXPECT_TRUE(receiver.has_gap());
  EXPECT_EQ(receiver.first_missing(), 2u);
  EXPECT_EQ(receiver.highest_seen(), 6u);
  EXPECT_EQ(receiver.cumulative_ack(), 1u);  // buffered is not delivered
  EXPECT_EQ(receiver.buffered_count(), 3u);
  EXPECT_EQ(receiver.buffered_bytes(), 6u);
  EXPECT_FALSE(receiver.next_buffered());  // 2 is still missing
  EXPECT_EQ(deliver_and_drain(receiver, 2, "m2"), (std::vector<std::string>{"m2", "m3"}));
  EXPECT_EQ(receiver.cumulative_ack(), 3u);
  EXPECT_EQ(receiver.first_missing(), 4u);
  EXPECT_TRUE(receiver.has_gap());
  EXPECT_EQ(deliver_and_drain(receiver, 4, "m4"), (std::vector<std::string>{"m4", "m5", "m6"}));
  EXPECT_EQ(receiver.cumulative_ack(), 6u);
  EXPECT_FALSE(receiver.has_gap());
  EXPECT_EQ(receiver.buffered_count(), 0u);
  EXPECT_EQ(receiver.buffered_bytes(), 0u);
  EXPECT_EQ(receiver.counters().delivered, 6u);
  EXPECT_EQ(receiver.counters().buffered, 3u);
  EXPECT_EQ(receiver.counters().gaps, 0u);
}

// The peer's keepalive names the last seq it sent: a lost tail becomes a gap that can be asked
// for; a value at or below what arrived changes nothing, a bogus one stays within the window.
TEST(ReliableReceiver, ATailThePeerSaysItSentIsMissing) {
  ReliableReceiver receiver(8, 1024);
  const auto t = ReliableReceiver::TimePoint{} + std::chrono::hours(1);
  ASSERT_EQ(receiver.accept(1, "a"), ReliableReceiver::Verdict::deliver);
  receiver.note_sent_through(1);
  EXPECT_FALSE(receiver.has_gap());
  EXPECT_FALSE(receiver.should_request_resend(t, std::chrono::milliseconds(100)));
  receiver.note_sent_through(3);  // 2 and 3 were lost on the line
  EXPECT_TRUE(receiver.has_gap());
  EXPECT_EQ(receiver.missing(10), (std::vector<std::uint64_t>{2, 3}));
  EXPECT_TRUE(receiver.should_request_resend(t, std::chrono::milliseconds(100)));
  ASSERT_EQ(receiver.accept(2, "b"), ReliableReceiver::Verdict::deliver);
  ASSERT_EQ(receiver.accept(3, "c"), ReliableReceiver::Verdict::deliver);
  EXPECT_FALSE(receiver.has_gap());
  receiver.note_sent_through(std::uint64_t{1} << 60);  // bogus: no further than the window
  EXPECT_EQ(receiver.missing(100).size(), 9u);  // the expected seq and the window of 8 after it
}

TEST(ReliableReceiver, DropsDuplicatesOfDeliveredAndOfBufferedMessages) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1, "m1"), Verdict::deliver);
  EXPECT_EQ(receiver.accept(1, "m1"), Verdict::duplicate);
  EXPECT_EQ(receiver.accept(0, ""), Verdict::duplicate);
  ASSERT_EQ(receiver.accept(3, "m3"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(3, "m3"), Verdict::duplicate);  // e.g. after a rewind
  EXPECT_EQ(receiver.buffered_count(), 1u);
  EXPECT_EQ(receiver.buffered_bytes(), 2u);
  EXPECT_EQ(deliver_and_drain(receiver, 2, "m2"), (std::vector<std::string>{"m2", "m3"}));
  EXPECT_EQ(receiver.accept(3, "m3"), Verdict::duplicate);
  EXPECT_EQ(receiver.counters().delivered, 3u);
  EXPECT_EQ(receiver.counters().duplicates, 4u);
  EXPECT_EQ(receiver.counters().buffered_duplicates, 1u);
}

TEST(ReliableReceiver, ReorderWindowBoundsWhatIsBuffered) {
  ReliableReceiver receiver(/*max_buffered_messages=*/4, /*max_buffered_bytes=*/1000);
  // Expecting 1: the window is 2..5.
  EXPECT_EQ(receiver.accept(5, "m5"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(6, "m6"), Verdict::gap);  // beyond the window: dropped
  EXPECT_EQ(receiver.accept(1000, "x"), Verdict::gap);
  EXPECT_EQ(receiver.accept(2, "m2"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(3, "m3"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(4, "m4"), Verdict::buffered);
  EXPECT_EQ(receiver.buffered_count(), 4u);
  EXPECT_EQ(receiver.counters().gaps, 2u);
  EXPECT_EQ(receiver.highest_seen(), 1000u);  // still counts as seen: 1 is missing
  EXPECT_EQ(deliver_and_drain(receiver, 1, "m1"),
            (std::vector<std::string>{"m1", "m2", "m3", "m4", "m5"}));
  EXPECT_TRUE(receiver.has_gap());  // 6 was dropped and must be asked for
  EXPECT_EQ(receiver.first_missing(), 6u);
  EXPECT_EQ(receiver.accept(10, "m10"), Verdict::buffered);  // the window moved with delivery
  EXPECT_EQ(receiver.accept(11, "m11"), Verdict::gap);
}

TEST(ReliableReceiver, ByteBoundGivesUpTheHighestSeqsForALowerOne) {
  ReliableReceiver receiver(/*max_buffered_messages=*/64, /*max_buffered_bytes=*/10);
  EXPECT_EQ(receiver.accept(5, "55555"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(6, "6666"), Verdict::buffered);
  EXPECT_EQ(receiver.accept(7, "77"), Verdict::gap);  // higher than all: it is the one dropped
  EXPECT_EQ(receiver.accept(3, "333333"), Verdict::buffered);  // evicts 6 and then 5
  EXPECT_EQ(receiver.buffered_count(), 1u);
  EXPECT_EQ(receiver.buffered_bytes(), 6u);
  EXPECT_EQ(receiver.accept(4, "4444"), Verdict::buffered);  // exactly full
  EXPECT_EQ(receiver.buffered_bytes(), 10u);
  EXPECT_EQ(receiver.accept(2, std::string(11, '2')), Verdict::gap);  // could never fit
  EXPECT_EQ(receiver.counters().evicted, 2u);
  EXPECT_EQ(receiver.counters().gaps, 2u);
  ASSERT_EQ(receiver.accept(1, "1"), Verdict::deliver);
  EXPECT_FALSE(receiver.next_buffered());  // 2 is still missing
  EXPECT_EQ(deliver_and_drain(receiver, 2, "22"),
            (std::vector<std::string>{"22", "333333", "4444"}));
  EXPECT_EQ(receiver.first_missing(), 5u);
  EXPECT_TRUE(receiver.has_gap());
}

TEST(ReliableReceiver, ListsTheHolesWithinTheReorderWindow) {
  ReliableReceiver receiver(/*max_buffered_messages=*/6, /*max_buffered_bytes=*/1000);
  EXPECT_TRUE(receiver.missing(16).empty());
  ASSERT_EQ(receiver.accept(1, "a"), Verdict::deliver);
  ASSERT_EQ(receiver.accept(3, "c"), Verdict::buffered);
  ASSERT_EQ(receiver.accept(4, "d"), Verdict::buffered);
  ASSERT_EQ(receiver.accept(6, "f"), Verdict::buffered);
  EXPECT_EQ(receiver.missing(16), (std::vector<std::uint64_t>{2, 5}));
  EXPECT_EQ(receiver.missing(1), (std::vector<std::uint64_t>{2}));
  // 20 lies beyond the window (expected + 1 .. expected + 6, i.e. 3..8): only up to 8 is listed.
  ASSERT_EQ(receiver.accept(20, "t"), Verdict::gap);
  EXPECT_EQ(receiver.missing(16), (std::vector<std::uint64_t>{2, 5, 7, 8}));
  EXPECT_EQ(deliver_and_drain(receiver, 2, "b").size(), 3u);
  EXPECT_EQ(receiver.missing(16), (std::vector<std::uint64_t>{5, 7, 8, 9, 10, 11}));
}

TEST(ReliableReceiver, ZeroBoundsMeanPureGoBackN) {
  ReliableReceiver receiver(0, 0);
  EXPECT_EQ(receiver.accept(2, "b"), Verdict::gap);
  EXPECT_EQ(receiver.accept(1, "a"), Verdict::deliver);
  EXPECT_FALSE(receiver.next_buffered());
  EXPECT_EQ(receiver.first_missing(), 2u);
}

TEST(ReliableReceiver, DeliversExactlyOnceEvenIfTheCallerDoesNotDrain) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(2, "m2"), Verdict::buffered);
  ASSERT_EQ(receiver.accept(1, "m1"), Verdict::deliver);
  // No drain: a retransmission of 2 is delivered and the buffered copy is gone.
  EXPECT_EQ(receiver.accept(2, "m2"), Verdict::deliver);
  EXPECT_FALSE(receiver.next_buffered());
  EXPECT_EQ(receiver.buffered_count(), 0u);
  EXPECT_EQ(receiver.buffered_bytes(), 0u);
  EXPECT_EQ(receiver.counters().delivered, 2u);
}

TEST(ReliableReceiver, ResetStartsExpectingExactlyTheGivenSeqAndForgetsTheBuffer) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1, "a"), Verdict::deliver);
  ASSERT_EQ(receiver.accept(5, "e"), Verdict::buffered);
  receiver.reset(42);  // the peer restarted; its hello says its stream starts at 42
  EXPECT_EQ(receiver.cumulative_ack(), 41u);
  EXPECT_EQ(receiver.buffered_count(), 0u);
  EXPECT_EQ(receiver.buffered_bytes(), 0u);
  EXPECT_FALSE(receiver.has_gap());
  EXPECT_EQ(receiver.accept(41, "x"), Verdict::duplicate);
  EXPECT_EQ(receiver.accept(43, "y"), Verdict::buffered);
  EXPECT_EQ(deliver_and_drain(receiver, 42, "x"), (std::vector<std::string>{"x", "y"}));
  receiver.reset(0);
  EXPECT_EQ(receiver.expected(), 1u);
  EXPECT_EQ(receiver.cumulative_ack(), 0u);
  EXPECT_FALSE(receiver.has_gap());
}

TEST(ReliableReceiver, ResendRequestsOnlyForAGapAndThrottledPerMissingSeqAndInterval) {
  ReliableReceiver receiver;
  EXPECT_FALSE(receiver.should_request_resend(kT0, kRto));  // nothing missing
  ASSERT_EQ(receiver.accept(1, "a"), Verdict::deliver);
  EXPECT_FALSE(receiver.should_request_resend(kT0, kRto));
  ASSERT_EQ(receiver.accept(3, "c"), Verdict::buffered);
  EXPECT_TRUE(receiver.should_request_resend(kT0, kRto));
  ASSERT_EQ(receiver.accept(4, "d"), Verdict::buffered);
  EXPECT_FALSE(receiver.should_request_resend(kT0 + 1ms, kRto));
  EXPECT_FALSE(receiver.should_request_resend(kT0 + kRto - 1ns, kRto));
  EXPECT_TRUE(receiver.should_request_resend(kT0 + kRto, kRto));  // the request may be lost
  ASSERT_EQ(receiver.accept(6, "f"), Verdict::buffered);
  ASSERT_EQ(receiver.accept(2, "b"), Verdict::deliver);
  receiver.drain([](std::string&&) {});
  EXPECT_EQ(receiver.first_missing(), 5u);  // the next hole: report it at once
  EXPECT_TRUE(receiver.should_request_resend(kT0 + kRto + 1ms, kRto));
  ASSERT_EQ(receiver.accept(5, "e"), Verdict::deliver);
  receiver.drain([](std::string&&) {});
  EXPECT_FALSE(receiver.should_request_resend(kT0 + 1h, kRto));  // all filled
  receiver.reset(10);
  ASSERT_EQ(receiver.accept(12, "l"), Verdict::buffered);
  EXPECT_TRUE(receiver.should_request_resend(kT0 + kRto + 2ms, kRto));
}

// ---------------------------------------------------------------------------------------------
// Both ends over a lossy, duplicating link that is cut and re-established at random.

struct LinkModel {
  double data_loss;
  double data_duplication;
  double ack_loss;
  double ack_reordering;
  double cut_per_tick;
};

enum class Recovery {
  selective,  // what the session does: single resends on request, on_retransmit_timeout()
  go_back_n,  // the previous behaviour, for comparison: every request or timeout rewinds
};

struct SimConfig {
  LinkModel model;
  Recovery recovery = Recovery::selective;
  bool nack_lists = false;        // resend requests also list further holes (missing() / on_nack())
  std::size_t max_messages = 64;  // sender's resend buffer
  std::size_t max_bytes = 900;
  std::size_t rx_buffered_messages = ReliableReceiver::kDefaultMaxBufferedMessages;
  std::size_t rx_buffered_bytes = ReliableReceiver::kDefaultMaxBufferedBytes;
  std::uint64_t messages = 20000;
  std::uint32_t seed = 1;
};

struct SimResult {
  int ticks = 0;
  int cuts = 0;
  std::uint64_t delivered_in_order = 0;  // checked against the produced sequence as it goes
  std::uint64_t refused_by_sender = 0;
  ReliableSender::Counters sender;
  ReliableReceiver::Counters receiver;
  std::uint64_t final_cumulative_ack = 0;
  std::size_t final_unacked_bytes = 0;
};

std::string encode_index(std::uint64_t index) {
  // Varying lengths, so that the byte bound is what binds most of the time.
  return std::to_string(index) + std::string(index % 23, '.');
}

std::uint64_t decode_index(std::string_view payload) {
  return std::stoull(std::string(payload.substr(0, payload.find('.'))));
}

// Runs until every message is delivered and acked (or a tick limit); fails the test on any
// out-of-order, duplicated or lost delivery or on a bound being exceeded.
void simulate(const SimConfig& config, SimResult& result) {
  constexpr auto kTick = 1ms;
  constexpr auto kSimRto = 40ms;
  constexpr auto kResendInterval = kSimRto / 4;  // as the session does: well below the rto
  constexpr int kMaxTicks = 2'000'000;
  const LinkModel& model = config.model;

  std::mt19937 rng(config.seed);
  auto chance = [&rng](double p) { return std::bernoulli_distribution(p)(rng); };
  auto below = [&rng](std::size_t n) {
    return std::uniform_int_distribution<std::size_t>(0, n - 1)(rng);
  };

  struct DataFrame {
    std::uint64_t seq;
    std::string payload;
  };
  struct AckFrame {
    std::uint64_t ack;
    bool resend;
    std::vector<std::uint64_t> nacks;
  };

  ReliableSender sender({.max_messages = config.max_messages, .max_bytes = config.max_bytes});
  ReliableReceiver receiver(config.rx_buffered_messages, config.rx_buffered_bytes);
  std::deque<DataFrame> data_in_flight;  // in order within one link
  std::vector<AckFrame> acks_in_flight;  // may overtake each other
  bool link_up = true;
  int ticks_until_reconnect = 0;
  sender.on_link_up();
  // Go-back-N's own request throttle, as the sender had it before selective repeat.
  std::optional<std::uint64_t> gbn_last_ack;
  TimePoint gbn_last_rewind{};

  TimePoint now = kT0;
  std::uint64_t next_to_produce = 0;

  auto send_ack = [&](bool resend) {
    if (chance(model.ack_loss)) return;
    acks_in_flight.push_back({receiver.cumulative_ack(), resend, {}});
    if (resend && config.nack_lists) acks_in_flight.back().nacks = receiver.missing(16);
  };
  auto deliver = [&](std::string_view payload) {
    ASSERT_EQ(decode_index(payload), result.delivered_in_order);
    ++result.delivered_in_order;
  };

  int& ticks = result.ticks;
  for (; ticks < kMaxTicks &&
         (result.delivered_in_order < config.messages || sender.unacked_count() > 0);
       ++ticks) {
    now += kTick;

    // The producer offers a burst; what is refused it keeps and offers again later. Half the time
    // it asks first, half the time it just pushes and looks at the result.
    for (int burst = 0; burst < 8 && next_to_produce < config.messages; ++burst) {
      std::string payload = encode_index(next_to_produce);
      if (chance(0.5) && !sender.can_accept(payload.size())) break;
      if (!sender.push(std::move(payload))) {
        ++result.refused_by_sender;
        break;
      }
      ++next_to_produce;
    }
    ASSERT_LE(sender.unacked_count(), config.max_messages);
    ASSERT_LE(sender.unacked_bytes(), config.max_bytes);
    ASSERT_LE(receiver.buffered_count(), config.rx_buffered_messages);
    ASSERT_LE(receiver.buffered_bytes(), config.rx_buffered_bytes);

    if (!link_up) {
      if (--ticks_until_reconnect > 0) continue;
      // Reconnected; the hello exchange tells the sender what the receiver has.
      link_up = true;
      sender.on_link_up();
      sender.on_ack(receiver.cumulative_ack(), now);
      sender.rewind();
    }
    if (chance(model.cut_per_tick)) {
      ++result.cuts;
      link_up = false;
      ticks_until_reconnect = 1 + static_cast<int>(below(30));
      data_in_flight.clear();
      acks_in_flight.clear();
      sender.on_link_down();
      continue;
    }

    for (int writes = 0; writes < 6; ++writes) {
      auto out = sender.next_to_send(now);
      if (!out) break;
      if (chance(model.data_loss)) continue;  // CRC error: the frame is discarded
      data_in_flight.push_back({out->seq, std::string(out->payload)});
      if (chance(model.data_duplication)) data_in_flight.push_back(data_in_flight.back());
    }

    for (int reads = 0; reads < 5 && !data_in_flight.empty(); ++reads) {
      const DataFrame frame = std::move(data_in_flight.front());
      data_in_flight.pop_front();
      const Verdict verdict = receiver.accept(frame.seq, frame.payload);
      if (verdict == Verdict::deliver) {
        deliver(frame.payload);
        receiver.drain([&](std::string&& payload) { deliver(payload); });
        if (::testing::Test::HasFatalFailure()) return;
      }
      if (receiver.should_request_resend(now, kResendInterval)) {
        send_ack(true);
      } else if (verdict == Verdict::deliver || verdict == Verdict::duplicate) {
        send_ack(false);  // for a duplicate: our earlier ack may have been lost
      }
    }
    // The session's watchdog: a lost retransmission is asked for again without new arrivals.
    if (receiver.should_request_resend(now, kResendInterval)) send_ack(true);

    for (int reads = 0; reads < 5 && !acks_in_flight.empty(); ++reads) {
      const std::size_t pick = chance(model.ack_reordering) ? below(acks_in_flight.size()) : 0;
      const AckFrame ack = std::move(acks_in_flight[pick]);
      acks_in_flight.erase(acks_in_flight.begin() + static_cast<std::ptrdiff_t>(pick));
      if (!ack.resend) {
        sender.on_ack(ack.ack, now);
      } else if (config.recovery == Recovery::selective) {
        sender.on_resend_request(ack.ack, now, kResendInterval);
        for (const std::uint64_t seq : ack.nacks) sender.on_nack(seq, now, kResendInterval);
      } else {
        sender.on_ack(ack.ack, now);
        if (ack.ack + 1 >= sender.send_base() &&
            (gbn_last_ack != ack.ack || now - gbn_last_rewind >= kSimRto)) {
          gbn_last_ack = ack.ack;
          gbn_last_rewind = now;
          sender.rewind();
        }
      }
    }

    if (sender.retransmit_due(now, kSimRto)) {
      if (config.recovery == Recovery::selective) {
        sender.on_retransmit_timeout();
      } else {
        sender.rewind();
      }
    }
  }
  result.sender = sender.counters();
  result.receiver = receiver.counters();
  result.final_cumulative_ack = receiver.cumulative_ack();
  result.final_unacked_bytes = sender.unacked_bytes();
}

struct PropertyCase {
  std::uint32_t seed;
  std::size_t rx_buffered_messages;
  std::size_t rx_buffered_bytes;
  bool nack_lists = false;
};

void PrintTo(const PropertyCase& c, std::ostream* os) {
  *os << "seed " << c.seed << ", rx buffer " << c.rx_buffered_messages << " msgs / "
      << c.rx_buffered_bytes << " bytes" << (c.nack_lists ? ", nack lists" : "");
}

class ReliableStreamProperty : public ::testing::TestWithParam<PropertyCase> {};

TEST_P(ReliableStreamProperty, DeliversEveryMessageExactlyOnceInOrderDespiteLossAndCuts) {
  SimConfig config{.model = {.data_loss = 0.03,
                             .data_duplication = 0.03,
                             .ack_loss = 0.15,
                             .ack_reordering = 0.3,
                             .cut_per_tick = 0.004}};
  config.seed = GetParam().seed;
  config.rx_buffered_messages = GetParam().rx_buffered_messages;
  config.rx_buffered_bytes = GetParam().rx_buffered_bytes;
  config.nack_lists = GetParam().nack_lists;
  SimResult result;
  simulate(config, result);
  if (HasFatalFailure()) return;
  std::cout << "ticks " << result.ticks << ", cuts " << result.cuts << ", sent "
            << result.sender.sent << ", selective " << result.sender.selective_retransmits
            << ", timeouts " << result.sender.timeouts << " (" << result.sender.timeout_rewinds
            << " rewinds), buffered " << result.receiver.buffered << ", dropped "
            << result.receiver.gaps << ", evicted " << result.receiver.evicted << "\n";

  ASSERT_LT(result.ticks, 2'000'000) << "no progress: delivered " << result.delivered_in_order;
  EXPECT_EQ(result.delivered_in_order, config.messages);
  EXPECT_EQ(result.receiver.delivered, config.messages);
  EXPECT_EQ(result.final_cumulative_ack, config.messages);
  EXPECT_EQ(result.sender.pushed, config.messages);
  EXPECT_EQ(result.sender.acked, config.messages);
  EXPECT_EQ(result.sender.overflow, result.refused_by_sender);
  EXPECT_EQ(result.sender.bogus_acks, 0u);
  EXPECT_EQ(result.final_unacked_bytes, 0u);
  // The run must have exercised what it claims to.
  EXPECT_GT(result.refused_by_sender, 0u);
  EXPECT_GT(result.cuts, 5);
  EXPECT_GT(result.receiver.duplicates, 0u);
  EXPECT_GT(result.sender.retransmitted, 0u);
  EXPECT_GT(result.sender.selective_retransmits, 0u);
  if (config.rx_buffered_messages > 0) {
    EXPECT_GT(result.receiver.buffered, 0u);
    EXPECT_GT(result.receiver.buffered_duplicates, 0u);
  }
  if (config.rx_buffered_bytes > 0 && config.rx_buffered_bytes < 200) {
    EXPECT_GT(result.receiver.gaps, 0u);  // the tight reorder buffer overflowed
  }
}

INSTANTIATE_TEST_SUITE_P(
    Seeds, ReliableStreamProperty,
    ::testing::Values(PropertyCase{1, 64, 64 * 1024}, PropertyCase{2, 64, 64 * 1024},
                      PropertyCase{3, 64, 64 * 1024}, PropertyCase{42, 64, 64 * 1024},
                      PropertyCase{2024, 64, 64 * 1024}, PropertyCase{7, 16, 100},
                      PropertyCase{8, 16, 100}, PropertyCase{9, 0, 0},
                      PropertyCase{10, 64, 64 * 1024, true}, PropertyCase{11, 64, 64 * 1024, true},
                      PropertyCase{12, 16, 100, true}));

// Efficiency: transmissions per delivered message over a link that only loses data frames.
TEST(ReliableStreamEfficiency, SelectiveRepeatResendsLittleMoreThanWhatWasLost) {
  for (const std::uint32_t seed : {1u, 2u, 3u}) {
    SimConfig config{.model = {.data_loss = 0.03,
                               .data_duplication = 0.0,
                               .ack_loss = 0.0,
                               .ack_reordering = 0.0,
                               .cut_per_tick = 0.0},
                     .max_messages = 64,
                     .max_bytes = 64 * 64};
    config.seed = seed;
    SimResult selective;
    simulate(config, selective);
    if (HasFatalFailure()) return;
    config.recovery = Recovery::go_back_n;
    config.rx_buffered_messages = 0;
    config.rx_buffered_bytes = 0;
    SimResult go_back_n;
    simulate(config, go_back_n);
    if (HasFatalFailure()) return;
    ASSERT_EQ(selective.delivered_in_order, config.messages);
    ASSERT_EQ(go_back_n.delivered_in_order, config.messages);

    const double messages = static_cast<double>(config.messages);
    const double selective_cost = static_cast<double>(selective.sender.sent) / messages;
    const double go_back_n_cost = static_cast<double>(go_back_n.sender.sent) / messages;
    std::cout << "seed " << seed << ": transmissions per message: selective repeat "
              << selective_cost << " (" << selective.ticks << " ticks), go-back-N "
              << go_back_n_cost << " (" << go_back_n.ticks << " ticks)\n";
    // A 3% loss needs 1/0.97 = 1.031 transmissions at best.
    EXPECT_LT(selective_cost, 1.3) << "seed " << seed;
    EXPECT_GT(go_back_n_cost, 2 * selective_cost) << "seed " << seed;
    EXPECT_LT(selective.ticks, go_back_n.ticks) << "seed " << seed;
  }
}

// A noisy serial line: a third of the frames is corrupted.
TEST(ReliableStreamEfficiency, NoisyLineCostsLittleMoreThanTheLossItself) {
  SimConfig config{.model = {.data_loss = 0.34,
                             .data_duplication = 0.0,
                             .ack_loss = 0.0,
                             .ack_reordering = 0.0,
                             .cut_per_tick = 0.0},
                   .max_messages = 64,
                   .max_bytes = 64 * 64,
                   .messages = 5000};
  SimResult selective;
  simulate(config, selective);
  if (HasFatalFailure()) return;
  config.nack_lists = true;
  SimResult with_nacks;
  simulate(config, with_nacks);
  if (HasFatalFailure()) return;
  config.nack_lists = false;
  config.recovery = Recovery::go_back_n;
  config.rx_buffered_messages = 0;
  config.rx_buffered_bytes = 0;
  SimResult go_back_n;
  simulate(config, go_back_n);
  if (HasFatalFailure()) return;
  ASSERT_EQ(selective.delivered_in_order, config.messages);
  ASSERT_EQ(with_nacks.delivered_in_order, config.messages);
  ASSERT_EQ(go_back_n.delivered_in_order, config.messages);
  const double messages = static_cast<double>(config.messages);
  const double selective_cost = static_cast<double>(selective.sender.sent) / messages;
  const double nacks_cost = static_cast<double>(with_nacks.sender.sent) / messages;
  const double go_back_n_cost = static_cast<double>(go_back_n.sender.sent) / messages;
  std::cout << "34% loss: transmissions per message: selective repeat " << selective_cost << " ("
            << selective.ticks << " ticks), with nack lists " << nacks_cost << " ("
            << with_nacks.ticks << " ticks), go-back-N " << go_back_n_cost << " ("
            << go_back_n.ticks << " ticks)\n";
  // 1 / (1 - 0.34) = 1.52 at best.
  EXPECT_LT(selective_cost, 1.8);
  EXPECT_LT(nacks_cost, 1.8);
  EXPECT_GT(go_back_n_cost, 2 * selective_cost);
  // Holes repaired all at once instead of one per round trip: the window keeps moving.
  EXPECT_LT(with_nacks.ticks, selective.ticks);
}

// The same with lossy and reordered acks that get lost and reordered: still far
// below go-back-N.
TEST(ReliableStreamEfficiency, StaysEfficientWithLossyAcks) {
  SimConfig config{.model = {.data_loss = 0.03,
                             .data_duplication = 0.0,
                             .ack_loss = 0.15,
                             .ack_reordering = 0.3,
                             .cut_per_tick = 0.0},
                   .max_messages = 64,
                   .max_bytes = 64 * 64};
  SimResult result;
  simulate(config, result);
  if (HasFatalFailure()) return;
  ASSERT_EQ(result.delivered_in_order, config.messages);
  const double cost =
      static_cast<double>(result.sender.sent) / static_cast<double>(config.messages);
  std::cout << "lossy acks: transmissions per message " << cost << ", timeouts "
            << result.sender.timeouts << " (" << result.sender.timeout_rewinds << " rewinds)\n";
  EXPECT_LT(cost, 1.3);
}

}  // namespace
}  // namespace canbridge::backbone
