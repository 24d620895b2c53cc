// The life of one request that crosses the backbone, from the moment it is sent to the one end
// its asker is told, with the rules that decide that end: one core for the tunnel's SDO requests
// (bridge/sdo_link_guard.hpp) and for the command endpoint's requests
// (bridge/remote_request_ledger.hpp), so that the two can never tell a request's outcome by
// different rules.
//
// A request is *open* while its answer is expected on the live link. When that link is lost, or
// the answer is overdue, it *awaits* its answer until a deadline: the gateway may have run it and
// resends what it answered on the next link. Without an answer by then it *ends unanswered*, and
// what its asker is told depends only on whether it may have run and on what it may change
// (end_unanswered()). Once told, an answer that arrives later is *late* and never reaches the
// asker, who could take it for the answer to a newer request. Pure: no clock is read, the caller
// passes the time.
#pragma once

#include <chrono>
#include <cstdint>

namespace canbridge::bridge {

// What a request may do to its node: decides how an end without an answer is told.
enum class RequestEffect : std::uint8_t {
  none,          // reads: running it twice or not at all is harmless
  changes_node,  // writes, NMT, node-id changes, flash, LSS
};

// How a request ended, as its asker is told (docs/canopen-bridging.md, "Outcomes").
enum class RequestEnd : std::uint8_t {
  answered,         // its answer, as the gateway (or the node) gave it
  not_sent,         // never left this side: it can never run, the asker is told at once
  timed_out,        // no answer in time, and the node is as before: it never ran, or only read
  outcome_unknown,  // it may have run and no answer can come any more: read the node back
};

// What is known of whether a request without an answer reached its node.
enum class MayHaveRun : std::uint8_t {
  no_never_sent,     // withheld or withdrawn before it left this side
  no_never_started,  // the gateway confirmed it removed the request before running it
  yes,               // it left this side: sent, acknowledged or running, no answer
};

class RequestLife {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  enum class Stage : std::uint8_t {
    idle,      // nothing asked, or the last request was answered or given up by its asker
    open,      // sent; its answer is expected on the live link (by deadline(), if one is set)
    awaiting,  // its link was lost or its answer is overdue: it may still come, by deadline()
    told,      // ended unanswered and its asker told so: a later answer is late
  };

  // Sent at `now`, by an asker who may change the node (`effect`); `deadline`: when the answer is
  // due (TimePoint::max(): the asker times itself).
  void sent(TimePoint now, RequestEffect effect, TimePoint deadline = TimePoint::max());
  // Not sent at all: it ends at once, never to run (the asker is told end()).
  RequestEnd refused();
  // The asker ended the request itself (its own abort, a cancel it asked for): nothing is owed.
  // An answer to a request already told failed stays late.
  void forget();
  // Nothing pending and nothing told: no request, or one that is never answered (the end of a
  // block upload).
  void clear() { stage_ = Stage::idle; }

  // The gateway reports the request running: its answer is expected again, by `deadline`.
  void running(TimePoint deadline);
  // Its answer can no longer come on the live link, but may come on the next one (or late on this
  // one) until `deadline`: the request awaits it.
  void await_answer(TimePoint deadline);

  enum class Answer : std::uint8_t {
    delivered,  // answers the open request: pass it on
    recovered,  // answers a request that awaited its answer across a lost link or a stall
    late,       // its asker was told already: drop it
  };
  Answer answered();

  // No answer can come any more (its deadline passed, the gateway restarted, the backbone gave
  // the request up): the end its asker is told. The request is told from now on.
  RequestEnd end_unanswered(MayHaveRun ran);

  Stage stage() const { return stage_; }
  bool pending() const { return stage_ == Stage::open || stage_ == Stage::awaiting; }
  bool awaiting() const { return stage_ == Stage::awaiting; }
  bool told() const { return stage_ == Stage::told; }
  TimePoint sent_at() const { return sent_at_; }
  TimePoint deadline() const { return deadline_; }
  bool due(TimePoint now) const { return now >= deadline_; }
  RequestEffect effect() const { return effect_; }
  // Whether an asker that sent the request at sent_at() can still be waiting for its end at
  // `now`, given how long its transfers stay open (zero or less: no bound). An end told later
  // than that reaches an asker that has moved on and cannot place it.
  bool asker_still_waits(TimePoint now, std::chrono::milliseconds open_for) const {
    return open_for.count() <= 0 || now - sent_at_ <= open_for;
  }

 private:
  TimePoint sent_at_{};
  TimePoint deadline_ = TimePoint::max();
  Stage stage_ = Stage::idle;
  RequestEffect effect_ = RequestEffect::none;
};

}  // namespace canbridge::bridge
