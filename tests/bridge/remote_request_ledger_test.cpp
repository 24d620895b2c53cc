// The life of the surface's remote requests (bridge/remote_request_ledger.hpp), driven with an
// injected time: an answer late past its deadline but within the gateway's resend window is the
// answer; a gateway that restarts or never answers leaves a write's outcome unknown and a read
// timed out; a request never handed to a gateway, or cancelled before it started, did nothing.
#include "bridge/remote_request_ledger.hpp"

#include <gtest/gtest.h>

#include <chrono>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using Ledger = RemoteRequestLedger;
using End = Ledger::End;
using Effect = Ledger::Effect;
using Result = Ledger::Result;

constexpr Ledger::GatewayId kGateway = 0, kOtherGateway = 1;
constexpr Ledger::SessionId kSession = 0x1111, kRestarted = 0x2222;

class RemoteRequestLedgerTest : public ::testing::Test {
 protected:
  Ledger ledger{Ledger::Options{.resend_window = 10s}};
  Ledger::TimePoint t0 = Ledger::TimePoint{} + 1h;
};

TEST_F(RemoteRequestLedgerTest, AResultBeforeTheDeadlineIsTheAnswer) {
  EXPECT_FALSE(ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s));
  EXPECT_EQ(ledger.next_deadline(), t0 + 6s);
  EXPECT_EQ(ledger.on_result(1, kGateway, Result::done), End::answered);
  EXPECT_EQ(ledger.open_requests(), 0u);
  EXPECT_FALSE(ledger.next_deadline());
  // Said once: a repeat (or a stranger's answer) is dropped.
  EXPECT_FALSE(ledger.on_result(1, kGateway, Result::done));
}

// Issue 27: the surface stalled past a write's deadline while the gateway ran it and resent its
// result on the new link. The result arriving within the window is the answer, not a time-out.
TEST_F(RemoteRequestLedgerTest, AStallPastTheDeadlineThenTheResentResultIsDelivered) {
  ledger.open(7, kGateway, kSession, Effect::changes_node, t0, 6s);
  EXPECT_TRUE(ledger.on_time(t0 + 5s).cancels.empty());
  // The surface runs again 7 s later: overdue, a cancel goes (it never starts late), no end yet.
  const Ledger::Due due = ledger.on_time(t0 + 7s);
  ASSERT_EQ(due.cancels.size(), 1u);
  EXPECT_EQ(due.cancels[0], std::make_pair(Ledger::RequestId{7}, kGateway));
  EXPECT_TRUE(due.ended.empty());
  EXPECT_TRUE(ledger.overdue(7));
  EXPECT_EQ(ledger.next_deadline(), t0 + 7s + 10s);
  // The gateway's session is the same one (it kept its result): nothing ends.
  EXPECT_TRUE(ledger.on_gateway_session(kGateway, kSession).empty());
  // The resent result, 2 s into the window: the answer (OK or the node's abort), as it says.
  EXPECT_EQ(ledger.on_result(7, kGateway, Result::done), End::answered);
  EXPECT_TRUE(ledger.on_time(t0 + 30s).ended.empty());
}

TEST_F(RemoteRequestLedgerTest, NoAnswerWithinTheWindowLeavesAWriteUnknownAndAReadTimedOut) {
  ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s);
  ledger.open(2, kGateway, kSession, Effect::none, t0, 6s);
  EXPECT_EQ(ledger.on_time(t0 + 6s).cancels.size(), 2u);
  EXPECT_TRUE(ledger.on_time(t0 + 16s - 1ms).ended.empty());
  const Ledger::Due due = ledger.on_time(t0 + 16s);
  ASSERT_EQ(due.ended.size(), 2u);
  for (const Ledger::Ended& e : due.ended) {
    EXPECT_EQ(e.end, e.id == 1 ? End::outcome_unknown : End::timed_out) << e.id;
  }
  EXPECT_EQ(ledger.open_requests(), 0u);
}

// The gateway was killed with the request taken and not answered; a new process connected.
TEST_F(RemoteRequestLedgerTest, AGatewayRestartedWithTheRequestUnansweredLeavesItsOutcomeUnknown) {
  ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s);
  ledger.open(2, kGateway, kSession, Effect::none, t0, 6s);
  ledger.open(3, kOtherGateway, kSession, Effect::changes_node, t0, 6s);
  const auto ended = ledger.on_gateway_session(kGateway, kRestarted);
  ASSERT_EQ(ended.size(), 2u);
  for (const Ledger::Ended& e : ended) {
    EXPECT_EQ(e.end, e.id == 1 ? End::outcome_unknown : End::timed_out) << e.id;
  }
  EXPECT_EQ(ledger.open_requests(), 1u);  // the other gateway's stays
  EXPECT_EQ(ledger.gateway_of(3), kOtherGateway);
  // A request sent to the new process is its own.
  ledger.open(4, kGateway, kRestarted, Effect::changes_node, t0, 6s);
  EXPECT_TRUE(ledger.on_gateway_session(kGateway, kRestarted).empty());
  // A gateway whose link is down has no session to compare: nothing ends for that.
  EXPECT_TRUE(ledger.on_gateway_session(kGateway, 0).empty());
}

TEST_F(RemoteRequestLedgerTest, ARequestNeverSentFailsAtOnceAndIsNeverHeld) {
  EXPECT_EQ(ledger.open(1, kGateway, 0, Effect::changes_node, t0, 6s), End::not_sent);
  EXPECT_EQ(ledger.open_requests(), 0u);
  EXPECT_FALSE(ledger.on_result(1, kGateway, Result::done));
}

TEST_F(RemoteRequestLedgerTest, TheGatewaysAnswerToTheDeadlineCancelSaysWhetherItRan) {
  for (Ledger::RequestId id : {1, 2, 3}) {
    ledger.open(id, kGateway, kSession, id == 3 ? Effect::none : Effect::changes_node, t0, 6s);
  }
  EXPECT_EQ(ledger.on_time(t0 + 6s).cancels.size(), 3u);
  // Taken off the gateway's queue before it started: it never ran.
  EXPECT_EQ(ledger.on_result(1, kGateway, Result::cancelled_not_started), End::timed_out);
  // Stopped on the bus while it ran: a write may have landed, a read changed nothing.
  EXPECT_EQ(ledger.on_result(2, kGateway, Result::cancelled_running), End::outcome_unknown);
  EXPECT_EQ(ledger.on_result(3, kGateway, Result::cancelled_running), End::timed_out);
}

TEST_F(RemoteRequestLedgerTest, OnlyTheGatewayAskedMayAnswer) {
  ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s);
  EXPECT_FALSE(ledger.on_result(1, kOtherGateway, Result::done));
  EXPECT_FALSE(ledger.on_progress(1, kOtherGateway, t0));
  EXPECT_EQ(ledger.on_result(1, kGateway, Result::done), End::answered);
}

TEST_F(RemoteRequestLedgerTest, ProgressRestartsTheWaitEvenWhenOverdue) {
  ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s);
  EXPECT_TRUE(ledger.on_progress(1, kGateway, t0 + 4s));
  EXPECT_EQ(ledger.next_deadline(), t0 + 10s);
  EXPECT_EQ(ledger.on_time(t0 + 10s).cancels.size(), 1u);
  // Still running at the gateway (the cancel will end it, and be answered): waiting again.
  EXPECT_TRUE(ledger.on_progress(1, kGateway, t0 + 11s));
  EXPECT_FALSE(ledger.overdue(1));
  EXPECT_EQ(ledger.next_deadline(), t0 + 17s);
}

TEST_F(RemoteRequestLedgerTest, TheClientsCancelClosesTheRequest) {
  ledger.open(1, kGateway, kSession, Effect::changes_node, t0, 6s);
  EXPECT_TRUE(ledger.cancel(1));
  EXPECT_FALSE(ledger.cancel(1));
  EXPECT_FALSE(ledger.next_deadline());
  EXPECT_FALSE(ledger.on_result(1, kGateway, Result::done));
}

}  // namespace
}  // namespace canbridge::bridge
