#include "bridge/request_life.hpp"

namespace canbridge::bridge {

void RequestLife::sent(TimePoint now, RequestEffect effect, TimePoint deadline) {
  sent_at_ = now;
  effect_ = effect;
  deadline_ = deadline;
  stage_ = Stage::open;
}

RequestEnd RequestLife::refused() {
  stage_ = Stage::told;
  deadline_ = TimePoint::max();
  return RequestEnd::not_sent;
}

void RequestLife::forget() {
  if (stage_ != Stage::told) stage_ = Stage::idle;
  deadline_ = TimePoint::max();
}

void RequestLife::running(TimePoint deadline) {
  if (stage_ == Stage::idle || stage_ == Stage::told) return;
  stage_ = Stage::open;
  deadline_ = deadline;
}

void RequestLife::await_answer(TimePoint deadline) {
  if (stage_ != Stage::open && stage_ != Stage::awaiting) return;
  stage_ = Stage::awaiting;
  deadline_ = deadline;
}

RequestLife::Answer RequestLife::answered() {
  const Stage was = stage_;
  if (was == Stage::told) return Answer::late;
  stage_ = Stage::idle;
  deadline_ = TimePoint::max();
  return was == Stage::awaiting ? Answer::recovered : Answer::delivered;
}

// The one rule for an end without an answer. A request that never left this side, or that the
// gateway confirmed it removed before it started, cannot have run. Any other may have: the
// gateway may have run it and its answer been lost with the link or the process. Then only a
// request that changes nothing can be called timed out; for one that may have changed the node
// the asker must learn that the outcome is unknown, never that it did not happen.
RequestEnd RequestLife::end_unanswered(MayHaveRun ran) {
  stage_ = Stage::told;
  deadline_ = TimePoint::max();
  switch (ran) {
    case MayHaveRun::no_never_sent:
      return RequestEnd::not_sent;
    case MayHaveRun::no_never_started:
      return RequestEnd::timed_out;
    case MayHaveRun::yes:
      break;
  }
  return effect_ == RequestEffect::none ? RequestEnd::timed_out : RequestEnd::outcome_unknown;
}

}  // namespace canbridge::bridge
