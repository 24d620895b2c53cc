// The one life of a request across the backbone (bridge/request_life.hpp), on its own with an
// injected time: an answer is delivered while the request is open, recovered while it awaits it
// across a lost link, and late once its asker was told; an end without an answer is "not sent"
// or "timed out" only when the request cannot have run or changes nothing, and "outcome
// unknown" for any request that may have changed its node.
#include "bridge/request_life.hpp"

#include <gtest/gtest.h>

#include <chrono>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using Stage = RequestLife::Stage;
using Answer = RequestLife::Answer;

const RequestLife::TimePoint t0 = RequestLife::TimePoint{} + 1h;

TEST(RequestLife, AnAnswerToAnOpenRequestIsDeliveredAndClosesIt) {
  RequestLife life;
  EXPECT_EQ(life.stage(), Stage::idle);
  life.sent(t0, RequestEffect::changes_node, t0 + 2s);
  EXPECT_TRUE(life.pending());
  EXPECT_EQ(life.deadline(), t0 + 2s);
  EXPECT_FALSE(life.due(t0 + 1999ms));
  EXPECT_TRUE(life.due(t0 + 2s));
  EXPECT_EQ(life.answered(), Answer::delivered);
  EXPECT_EQ(life.stage(), Stage::idle);
  EXPECT_FALSE(life.pending());
}

TEST(RequestLife, AnAnswerWhileAwaitingItAcrossALostLinkIsRecovered) {
  RequestLife life;
  life.sent(t0, RequestEffect::changes_node);
  EXPECT_EQ(life.deadline(), RequestLife::TimePoint::max());  // the asker times itself
  life.await_answer(t0 + 1600ms);
  EXPECT_TRUE(life.awaiting());
  EXPECT_TRUE(life.pending());
  EXPECT_EQ(life.deadline(), t0 + 1600ms);
  EXPECT_EQ(life.answered(), Answer::recovered);
  EXPECT_EQ(life.stage(), Stage::idle);
}

TEST(RequestLife, AnAnswerAfterTheAskerWasToldIsLateUntilANewRequest) {
  RequestLife life;
  life.sent(t0, RequestEffect::changes_node);
  life.await_answer(t0 + 1600ms);
  EXPECT_EQ(life.end_unanswered(MayHaveRun::yes), RequestEnd::outcome_unknown);
  EXPECT_TRUE(life.told());
  EXPECT_EQ(life.answered(), Answer::late);
  EXPECT_EQ(life.answered(), Answer::late);  // every later answer too
  life.forget();                             // the asker's own abort does not make it current
  EXPECT_EQ(life.answered(), Answer::late);
  life.sent(t0 + 3s, RequestEffect::none);  // a newer request: its answer is current again
  EXPECT_EQ(life.answered(), Answer::delivered);
}

TEST(RequestLife, TheEndWithoutAnAnswerSaysOnlyWhatIsKnown) {
  for (const RequestEffect effect : {RequestEffect::none, RequestEffect::changes_node}) {
    const bool writes = effect == RequestEffect::changes_node;
    RequestLife life;
    life.sent(t0, effect);
    EXPECT_EQ(life.end_unanswered(MayHaveRun::no_never_sent), RequestEnd::not_sent);
    life.sent(t0, effect);
    EXPECT_EQ(life.end_unanswered(MayHaveRun::no_never_started), RequestEnd::timed_out);
    life.sent(t0, effect);
    // A read that may have run is harmless; a write that may have run is unknown, never "failed".
    EXPECT_EQ(life.end_unanswered(MayHaveRun::yes),
              writes ? RequestEnd::outcome_unknown : RequestEnd::timed_out);
    EXPECT_EQ(life.deadline(), RequestLife::TimePoint::max());
  }
}

TEST(RequestLife, ARefusedRequestEndsAtOnceAndItsAnswerWouldBeLate) {
  RequestLife life;
  EXPECT_EQ(life.refused(), RequestEnd::not_sent);
  EXPECT_TRUE(life.told());
  EXPECT_EQ(life.answered(), Answer::late);
}

TEST(RequestLife, TheAskerMovingOnOwesNothingAndLetsAnAnswerThrough) {
  RequestLife life;
  life.sent(t0, RequestEffect::changes_node);
  life.await_answer(t0 + 1s);
  life.forget();
  EXPECT_EQ(life.stage(), Stage::idle);
  EXPECT_FALSE(life.pending());
  EXPECT_EQ(life.deadline(), RequestLife::TimePoint::max());
  // Nothing pending: an answer is for an asker on the module bus, not a late one.
  EXPECT_EQ(life.answered(), Answer::delivered);
}

TEST(RequestLife, RunningAtTheGatewayMakesAnOverdueRequestOpenAgain) {
  RequestLife life;
  life.sent(t0, RequestEffect::changes_node, t0 + 6s);
  life.await_answer(t0 + 16s);  // overdue: cancel sent, the answer awaited for the window
  life.running(t0 + 20s);       // the gateway reports it running: its answer is expected again
  EXPECT_EQ(life.stage(), Stage::open);
  EXPECT_EQ(life.deadline(), t0 + 20s);
  EXPECT_EQ(life.answered(), Answer::delivered);
}

TEST(RequestLife, TransitionsOfARequestThatIsNotPendingChangeNothing) {
  RequestLife life;
  life.running(t0 + 1s);
  life.await_answer(t0 + 1s);
  EXPECT_EQ(life.stage(), Stage::idle);
  EXPECT_EQ(life.refused(), RequestEnd::not_sent);
  life.running(t0 + 1s);
  life.await_answer(t0 + 1s);
  EXPECT_TRUE(life.told());
  EXPECT_EQ(life.deadline(), RequestLife::TimePoint::max());
}

TEST(RequestLife, AnEndIsWantedOnlyWhileItsAskerCanStillBeWaiting) {
  RequestLife life;
  life.sent(t0, RequestEffect::none);
  EXPECT_TRUE(life.asker_still_waits(t0 + 2s, 2s));
  EXPECT_FALSE(life.asker_still_waits(t0 + 2001ms, 2s));
  EXPECT_TRUE(life.asker_still_waits(t0 + 1h, 0ms));  // no bound known
}

}  // namespace
}  // namespace canbridge::bridge
