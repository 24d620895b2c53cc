// The requests the surface's remote access has handed to gateways, each followed from sending to
// the one end its client is told by the rules of bridge/request_life.hpp, so that no request is
// reported failed when it may have been done. Pure: request ids, gateway sessions, results and an
// injected time in; what to send (cancels) and how each request ended out.
//
// A request is *open* until its answer deadline, then *overdue*: the surface asks the gateway to
// cancel it and keeps waiting, for `resend_window` more, for the gateway's one answer. The
// session delivers requests, cancels and results exactly once and in order as long as neither
// process restarts, so a result the gateway resends after a stall or a cut still arrives, and a
// cancel that reaches the gateway first is answered "cancelled" (never run, or stopped). Only
// when no answer can come any more (the window passed, or the gateway is a new process) does the
// surface decide without one: a request that changes nothing (a read) has timed out; one that may
// have changed the node has an unknown outcome, and says so.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <set>
#include <unordered_map>
#include <utility>
#include <vector>

#include "bridge/request_life.hpp"

namespace canbridge::bridge {

class RemoteRequestLedger {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  using RequestId = std::uint64_t;
  using GatewayId = std::uint32_t;
  using SessionId = std::uint64_t;  // a gateway process's backbone session id; 0: none (down)

  struct Options {
    // How long an overdue request still waits for the gateway's answer: the backbone's dead-link
    // detection, the gateway's reconnect and the resend of what it holds, after the surface (or
    // the link) stalled past the answer deadline.
    std::chrono::milliseconds resend_window{10000};
  };

  // What the request may do to the node: decides how an end without an answer is told. Reads
  // (SDO upload, the node table) change nothing; writes, NMT, set-node-id, flash and LSS do.
  using Effect = RequestEffect;

  // What the gateway answered.
  enum class Result : std::uint8_t {
    done,                   // its outcome, success or failure
    cancelled_not_started,  // the surface's cancel removed it from the gateway's queue
    cancelled_running,      // the surface's cancel stopped it while it ran on the bus
  };

  // answered: the gateway's result, as it says; not_sent: never handed to a gateway (none
  // connected), never executed; timed_out: no result in time, and it never ran or changes
  // nothing; outcome_unknown: it may have run, no answer can come any more, the node must be
  // read back.
  using End = RequestEnd;
  struct Ended {
    RequestId id = 0;
    End end = End::answered;
  };
  // What the deadlines decided: cancels to send (request, its gateway), and ends.
  struct Due {
    std::vector<std::pair<RequestId, GatewayId>> cancels;
    std::vector<Ended> ended;
  };

  explicit RemoteRequestLedger(Options options) : options_(options) {}

  // A request handed to `gateway`'s current session `session`, answered within `within` of `now`.
  // A gateway without a session (0: not connected) never gets it: End::not_sent, at once.
  std::optional<End> open(RequestId id, GatewayId gateway, SessionId session, Effect effect,
                          TimePoint now, std::chrono::milliseconds within);
  // The gateway reports progress: it is running the request, whose wait starts again (`within`
  // as given to open()). False: no such request of that gateway (drop the report).
  bool on_progress(RequestId id, GatewayId from, TimePoint now);
  // The gateway's result. nullopt: no such open request of that gateway (an answer to one that
  // ended already, or to a surface process before this one): drop it.
  std::optional<End> on_result(RequestId id, GatewayId from, Result result);
  // The client gave up: closed now (the caller tells the gateway). False: not open.
  bool cancel(RequestId id);
  // Deadlines up to `now`: requests that became overdue (cancel each), and overdue ones whose
  // resend window passed.
  Due on_time(TimePoint now);
  // The gateway's session now (its latest hello; it is kept while its link is down). A new one
  // is a new process, which never answers what the old one was asked: those requests end now.
  std::vector<Ended> on_gateway_session(GatewayId gateway, SessionId session);

  std::optional<TimePoint> next_deadline() const;
  std::size_t open_requests() const { return requests_.size(); }
  std::optional<GatewayId> gateway_of(RequestId id) const;
  bool overdue(RequestId id) const;

 private:
  struct Request {
    GatewayId gateway = 0;
    SessionId session = 0;
    std::chrono::milliseconds within{0};
    // Open until its answer deadline; then overdue (awaiting): its cancel sent, the answer
    // awaited until the resend window's end.
    RequestLife life;
  };

  // Moves `request`'s deadline (in deadlines_ too) by `change`, a RequestLife transition.
  template <typename Change>
  void move_deadline(RequestId id, Request& request, Change&& change) {
    deadlines_.erase({request.life.deadline(), id});
    change(request.life);
    deadlines_.emplace(request.life.deadline(), id);
  }
  void close(RequestId id);

  Options options_;
  std::unordered_map<RequestId, Request> requests_;
  std::set<std::pair<TimePoint, RequestId>> deadlines_;
};

}  // namespace canbridge::bridge
