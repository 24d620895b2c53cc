#include "backbone/reliable_channel.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <deque>
#include <random>
#include <stdexcept>
#include <string>
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

TEST(ReliableSender, ResendRequestAppliesTheAckAndRewinds) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  EXPECT_TRUE(sender.on_resend_request(2, kT0, kRto));
  EXPECT_EQ(sender.send_base(), 3u);
  EXPECT_EQ(send_all(sender, kT0), (std::vector<std::uint64_t>{3, 4, 5}));
}

TEST(ReliableSender, IdenticalResendRequestsRewindOncePerRto) {
  ReliableSender sender = connected_sender();
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(sender.push("x"));
  send_all(sender, kT0);
  ASSERT_TRUE(sender.on_resend_request(2, kT0, kRto));
  send_all(sender, kT0);
  // One request per message that arrived after the gap: none of them may rewind again.
  for (int i = 0; i < 5; ++i) EXPECT_FALSE(sender.on_resend_request(2, kT0 + 10ms * i, kRto));
  EXPECT_FALSE(sender.has_unsent());
  EXPECT_FALSE(sender.on_resend_request(2, kT0 + kRto - 1ns, kRto));
  // The retransmission was lost too: after an rto the same request is honoured again.
  EXPECT_TRUE(sender.on_resend_request(2, kT0 + kRto, kRto));
  EXPECT_EQ(sender.next_to_send(kT0 + kRto)->seq, 3u);
  send_all(sender, kT0 + kRto);
  // A different gap is a new request, even within the rto.
  EXPECT_TRUE(sender.on_resend_request(6, kT0 + kRto + 1ms, kRto));
  EXPECT_EQ(sender.next_to_send(kT0 + kRto)->seq, 7u);
}

TEST(ReliableSender, StaleOrBogusResendRequestsDoNotRewind) {
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

// ---------------------------------------------------------------------------------------------
// ReliableReceiver

TEST(ReliableReceiver, DeliversInOrderAndAcksCumulatively) {
  ReliableReceiver receiver;
  EXPECT_EQ(receiver.cumulative_ack(), 0u);
  EXPECT_EQ(receiver.accept(1), Verdict::deliver);
  EXPECT_EQ(receiver.accept(2), Verdict::deliver);
  EXPECT_EQ(receiver.cumulative_ack(), 2u);
  EXPECT_EQ(receiver.expected(), 3u);
  EXPECT_EQ(receiver.counters().delivered, 2u);
}

TEST(ReliableReceiver, DropsDuplicatesAndWhatFollowsAGap) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1), Verdict::deliver);
  EXPECT_EQ(receiver.accept(1), Verdict::duplicate);
  EXPECT_EQ(receiver.accept(0), Verdict::duplicate);
  EXPECT_EQ(receiver.accept(3), Verdict::gap);  // 2 was lost
  EXPECT_EQ(receiver.accept(4), Verdict::gap);
  EXPECT_EQ(receiver.cumulative_ack(), 1u);
  EXPECT_EQ(receiver.accept(2), Verdict::deliver);
  EXPECT_EQ(receiver.accept(3), Verdict::deliver);
  EXPECT_EQ(receiver.accept(2), Verdict::duplicate);
  EXPECT_EQ(receiver.counters().delivered, 3u);
  EXPECT_EQ(receiver.counters().duplicates, 3u);
  EXPECT_EQ(receiver.counters().gaps, 2u);
}

TEST(ReliableReceiver, ResetStartsExpectingExactlyTheGivenSeq) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1), Verdict::deliver);
  receiver.reset(42);  // the peer restarted; its hello says its stream starts at 42
  EXPECT_EQ(receiver.cumulative_ack(), 41u);
  EXPECT_EQ(receiver.accept(41), Verdict::duplicate);
  EXPECT_EQ(receiver.accept(43), Verdict::gap);
  EXPECT_EQ(receiver.accept(42), Verdict::deliver);
  receiver.reset(0);
  EXPECT_EQ(receiver.expected(), 1u);
  EXPECT_EQ(receiver.cumulative_ack(), 0u);
}

TEST(ReliableReceiver, ResendRequestsAreThrottledPerExpectedSeqAndRto) {
  ReliableReceiver receiver;
  ASSERT_EQ(receiver.accept(1), Verdict::deliver);
  ASSERT_EQ(receiver.accept(3), Verdict::gap);
  EXPECT_TRUE(receiver.should_request_resend(kT0, kRto));
  ASSERT_EQ(receiver.accept(4), Verdict::gap);
  EXPECT_FALSE(receiver.should_request_resend(kT0 + 1ms, kRto));
  EXPECT_FALSE(receiver.should_request_resend(kT0 + kRto - 1ns, kRto));
  EXPECT_TRUE(receiver.should_request_resend(kT0 + kRto, kRto));  // the request may be lost
  ASSERT_EQ(receiver.accept(2), Verdict::deliver);
  ASSERT_EQ(receiver.accept(5), Verdict::gap);  // a new gap: report it at once
  EXPECT_TRUE(receiver.should_request_resend(kT0 + kRto + 1ms, kRto));
  receiver.reset(10);
  ASSERT_EQ(receiver.accept(12), Verdict::gap);
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

std::string encode_index(std::uint64_t index) {
  // Varying lengths, so that the byte bound is what binds most of the time.
  return std::to_string(index) + std::string(index % 23, '.');
}

std::uint64_t decode_index(std::string_view payload) {
  return std::stoull(std::string(payload.substr(0, payload.find('.'))));
}

class ReliableStreamProperty : public ::testing::TestWithParam<std::uint32_t> {};

TEST_P(ReliableStreamProperty, DeliversEveryMessageExactlyOnceInOrderDespiteLossAndCuts) {
  constexpr std::uint64_t kMessages = 20000;
  constexpr std::size_t kMaxMessages = 64;
  constexpr std::size_t kMaxBytes = 900;
  constexpr auto kTick = 1ms;
  constexpr auto kSimRto = 40ms;
  constexpr int kMaxTicks = 2'000'000;
  const LinkModel model{.data_loss = 0.03,
                        .data_duplication = 0.03,
                        .ack_loss = 0.15,
                        .ack_reordering = 0.3,
                        .cut_per_tick = 0.002};

  std::mt19937 rng(GetParam());
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
  };

  ReliableSender sender({.max_messages = kMaxMessages, .max_bytes = kMaxBytes});
  ReliableReceiver receiver;
  std::deque<DataFrame> data_in_flight;  // in order within one link
  std::vector<AckFrame> acks_in_flight;  // may overtake each other
  bool link_up = true;
  int ticks_until_reconnect = 0;
  sender.on_link_up();

  TimePoint now = kT0;
  std::uint64_t next_to_produce = 0;
  std::uint64_t next_to_deliver = 0;
  std::uint64_t refused_by_sender = 0;
  int cuts = 0;
  int ticks = 0;

  auto send_ack = [&](bool resend) {
    if (!chance(model.ack_loss)) acks_in_flight.push_back({receiver.cumulative_ack(), resend});
  };

  for (; ticks < kMaxTicks && (next_to_deliver < kMessages || sender.unacked_count() > 0);
       ++ticks) {
    now += kTick;

    // The producer offers a burst; what is refused it keeps and offers again later. Half the time
    // it asks first, half the time it just pushes and looks at the result.
    for (int burst = 0; burst < 8 && next_to_produce < kMessages; ++burst) {
      std::string payload = encode_index(next_to_produce);
      if (chance(0.5) && !sender.can_accept(payload.size())) break;
      if (!sender.push(std::move(payload))) {
        ++refused_by_sender;
        break;
      }
      ++next_to_produce;
    }
    ASSERT_LE(sender.unacked_count(), kMaxMessages);
    ASSERT_LE(sender.unacked_bytes(), kMaxBytes);

    if (!link_up) {
      if (--ticks_until_reconnect > 0) continue;
      // Reconnected; the hello exchange tells the sender what the receiver has.
      link_up = true;
      sender.on_link_up();
      sender.on_ack(receiver.cumulative_ack(), now);
      sender.rewind();
    }
    if (chance(model.cut_per_tick)) {
      ++cuts;
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
      switch (receiver.accept(frame.seq)) {
        case Verdict::deliver:
          ASSERT_EQ(decode_index(frame.payload), next_to_deliver) << "seq " << frame.seq;
          ++next_to_deliver;
          send_ack(false);
          break;
        case Verdict::duplicate:
          send_ack(false);  // our earlier ack may have been lost
          break;
        case Verdict::gap:
          if (receiver.should_request_resend(now, kSimRto)) send_ack(true);
          break;
      }
    }

    for (int reads = 0; reads < 5 && !acks_in_flight.empty(); ++reads) {
      const std::size_t pick = chance(model.ack_reordering) ? below(acks_in_flight.size()) : 0;
      const AckFrame ack = acks_in_flight[pick];
      acks_in_flight.erase(acks_in_flight.begin() + static_cast<std::ptrdiff_t>(pick));
      if (ack.resend) {
        sender.on_resend_request(ack.ack, now, kSimRto);
      } else {
        sender.on_ack(ack.ack, now);
      }
    }

    if (sender.retransmit_due(now, kSimRto)) sender.rewind();
  }

  ASSERT_LT(ticks, kMaxTicks) << "no progress: delivered " << next_to_deliver;
  EXPECT_EQ(next_to_deliver, kMessages);
  EXPECT_EQ(receiver.counters().delivered, kMessages);
  EXPECT_EQ(receiver.cumulative_ack(), kMessages);
  EXPECT_EQ(sender.counters().pushed, kMessages);
  EXPECT_EQ(sender.counters().acked, kMessages);
  EXPECT_EQ(sender.counters().overflow, refused_by_sender);
  EXPECT_EQ(sender.counters().bogus_acks, 0u);
  EXPECT_EQ(sender.unacked_bytes(), 0u);
  // The run must have exercised what it claims to.
  EXPECT_GT(refused_by_sender, 0u);
  EXPECT_GT(cuts, 5);
  EXPECT_GT(receiver.counters().gaps, 0u);
  EXPECT_GT(receiver.counters().duplicates, 0u);
  EXPECT_GT(sender.counters().retransmitted, 0u);
}

INSTANTIATE_TEST_SUITE_P(Seeds, ReliableStreamProperty, ::testing::Values(1u, 2u, 3u, 42u, 2024u));

}  // namespace
}  // namespace canbridge::backbone
