// Keeps a surface master's SDO client from hanging on nodes whose gateway link is down: a request
// to such a node is answered at once with abort 0x05040000 (SDO protocol timed out) instead of
// silence; a request in flight when a link drops gets its answer if the next link brings it in
// time, else the same abort before its master's own time-out, and so does one whose answer is
// overdue on a live link (docs/canopen-bridging.md).
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "bridge/gateway_claims.hpp"
#include "bridge/request_life.hpp"
#include "can/frame.hpp"
#include "canopen/cob_id.hpp"

namespace canbridge::bridge {

// The abort code a master sees for a node behind a lost link (CiA 301: SDO protocol timed out).
inline constexpr std::uint32_t kLinkDownAbort = 0x05040000;

// Pure: frames and the time in, frames out. Gateways are small integers chosen by the caller.
class SdoLinkGuard {
 public:
  using GatewayId = std::uint32_t;
  using Clock = std::chrono::steady_clock;

  struct Options {
    // How long a master's SDO request can still be open at its master: an abort for a request
    // older than this (a link that drops long after the request to an absent node went out)
    // reaches a master that has moved on and cannot place it, so it is dropped and counted
    // instead. Zero: no bound.
    std::chrono::milliseconds transfer_open_for{0};
    // How long after a request went out its answer may still be delivered. Past this, the master
    // gets the abort instead (a little before its own time-out, so that it learns the real
    // outcome is unknown from the abort rather than from silence), whether the link dropped
    // meanwhile (the gateway may have executed the request; its answer crosses on the next link
    // if that comes in time) or is still up (the answer was lost on a bad line, the gateway gave
    // it up after reliable_max_age_ms, or the node never answered). Zero: no deadline; the abort
    // comes at once when the link drops, and a live link's request waits for its answer.
    std::chrono::milliseconds answer_wait{0};
  };

  SdoLinkGuard() = default;
  explicit SdoLinkGuard(Options options) : options_(options) {}

  struct Counters {
    std::uint64_t aborted_at_once = 0;    // requests to a node whose gateway was down
    std::uint64_t aborted_in_flight = 0;  // requests pending when their gateway went down
    // Requests on a live link whose answer had not come within Options::answer_wait.
    std::uint64_t aborted_overdue = 0;
    // Requests pending when their gateway went down whose answer the next link brought in time.
    std::uint64_t answers_recovered = 0;
    std::uint64_t late_responses_dropped = 0;  // answers to requests the master saw aborted
    // Answers that cannot answer the master's pending request (another command class, object
    // or toggle): the answer to an older request, executed just before a link cut and aborted
    // toward the master, arriving once the master has sent a newer one.
    std::uint64_t stale_responses_dropped = 0;
    std::uint64_t aborted_discarded = 0;  // requests the backbone gave up (too old, old process)
    std::uint64_t aborted_not_forwarded = 0;  // requests the surface could not queue
    // Aborts not sent: their request was older than Options::transfer_open_for.
    std::uint64_t stale_aborts_dropped = 0;
    // Requests withdrawn when their gateway's link went down, each counted once: one per node
    // with a request pending, which the abort of on_gateway_down() answers (or, if stale, drops
    // and counts); the others, whose master had its answer already (an answer, an abort, its
    // own abort, or a newer request it sent instead); and those to nodes the guard does not
    // follow (no gateway claims them), whose master gets no abort from the guard.
    std::uint64_t withdrawn_pending = 0;
    std::uint64_t withdrawn_answered_before = 0;
    std::uint64_t withdrawn_untracked = 0;

    // Requests answered with 0x05040000 because of their link (down, or could not queue).
    std::uint64_t aborted() const {
      return aborted_at_once + aborted_in_flight + aborted_not_forwarded;
    }
  };

  // A frame a gateway sent towards the surface: its node-addressed COB-IDs (heartbeats, EMCY,
  // PDOs, SDO responses) tell which surface nodes the gateway owns; an SDO response ends the
  // transfer step in flight for that node. False for an SDO response that must not reach the
  // master: it answers a request the master was told had failed (aborted when the link dropped,
  // delivered once the link came back), and could be taken for the answer to a newer request.
  // Once the master has sent a request to the node, only a response that can answer it passes:
  // an abort naming the transfer's object (or none), or the response class of the request
  // (download/upload initiate, segment, block) naming the same object (initiates) or carrying
  // the same toggle (segments).
  [[nodiscard]] bool on_gateway_frame(GatewayId gateway, const can::Frame& frame);
  // The gateway reported the node in its node table (booted, renamed, ...): it owns the node
  // even before the node has sent anything through it.
  void note_owner(GatewayId gateway, canopen::NodeId node);
  // The gateway's hello claims these surface nodes: it owns them before any has sent a frame,
  // so a request to one is tracked, and aborted if the link drops, even if the node is silent.
  void note_claims(GatewayId gateway, const GatewayClaims& claims);

  // A frame from the surface bus, while `gateway_up(g)` tells which gateways have a live link.
  // An SDO request to a node owned by a gateway that is down gets `reply` (the abort) and must
  // not be forwarded; everything else is forwarded (and an SDO request is noted as in flight,
  // sent at `now`).
  struct Verdict {
    bool forward = true;
    std::optional<can::Frame> reply;
  };
  template <typename GatewayUp>
  Verdict on_surface_frame(const can::Frame& frame, GatewayUp&& gateway_up,
                           Clock::time_point now = {});

  // A frame on_surface_frame let through that the surface could not queue for its gateway: for
  // an SDO request, the abort the master gets instead of silence.
  std::optional<can::Frame> on_not_forwarded(const can::Frame& frame);

  // A request the surface withdrew (never to be sent) as its gateway's link went down, before
  // on_gateway_down(): counted by how its master gets, or got, its answer.
  void on_request_withdrawn(const can::Frame& request);

  // The gateway's link went down at `now`: the aborts for the SDO requests in flight to its
  // nodes that its master can still be waiting for (Options::transfer_open_for) and whose answer
  // can no longer come in time (Options::answer_wait); the others wait for it until
  // next_deadline().
  std::vector<can::Frame> on_gateway_down(GatewayId gateway, Clock::time_point now = {});

  // A new process of the gateway: the answers its old process held are lost with it, so the
  // requests waiting for one get their aborts now.
  std::vector<can::Frame> on_gateway_restart(GatewayId gateway, Clock::time_point now = {});

  // When the first pending request must be given up (Options::answer_wait); nullopt when none
  // has a deadline.
  std::optional<Clock::time_point> next_deadline() const;
  // The aborts of the requests whose answer did not come in time (Options::answer_wait). For one
  // whose link is still up, `withdraw(node)` is called first: the surface takes the node's SDO
  // requests out of what it has queued or sent unacknowledged, so that a request its master is
  // about to be told failed cannot reach the node later (it reports each withdrawn request with
  // on_request_withdrawn()).
  using Withdraw = std::function<void(canopen::NodeId node)>;
  std::vector<can::Frame> on_time(Clock::time_point now, const Withdraw& withdraw = nullptr);

  // A request forwarded earlier will never reach its node (the backbone gave it up: too old, or
  // queued for a gateway process that is gone): the abort for its master, unless the master has
  // its answer already (a response, an abort, its own abort). Requests to nodes no gateway has
  // claimed yet are not followed, so each of them gets an abort.
  std::optional<can::Frame> on_request_discarded(const can::Frame& request,
                                                 Clock::time_point now = {});

  std::optional<GatewayId> owner_of(canopen::NodeId node) const;
  const Counters& counters() const { return counters_; }

 private:
  // The answer the node's pending request expects (set by the master's last request).
  enum class Expect : std::uint8_t {
    untracked,                // the master never sent a request: nothing to match against
    nothing,                  // no request pending: any SDO response is stale or late
    download_initiate,        // scs 3 + same object
    upload_initiate,          // scs 2 + same object
    download_segment,         // scs 1 + same toggle
    upload_segment,           // scs 0 + same toggle
    block_download_initiate,  // scs 5 ss 0 + same object
    block_upload_initiate,    // scs 6 ss 0 + same object (or scs 2: protocol switch)
    block_download,           // sub-blocks: master frames are segments; scs 5 answers
    block_upload,             // server frames are segments: every response passes
  };
  struct Node {
    bool owned = false;
    GatewayId gateway = 0;
    // The master's last request to the node: open until its response, awaiting it across a lost
    // link, or told (aborted) so that a late response never reaches the master.
    RequestLife request;
    std::uint8_t mux[3] = {0, 0, 0};  // index (LE) and sub-index of the transfer in progress
    Expect expect = Expect::untracked;
    std::uint8_t toggle = 0;  // segments: bit 4 of the master's segment request
    // The pending request was withdrawn (on_request_withdrawn): an older one still in the
    // queue was answered before.
    bool withdrawn = false;
  };
  // The pending request of `n` ends aborted (or stale, past the transfer's life): the abort for
  // its master, if one is still wanted (counted in `aborted`).
  std::optional<can::Frame> abort_unanswered(canopen::NodeId node, Node& n, Clock::time_point now,
                                             std::uint64_t& aborted);
  // Whether `n`'s pending request has a deadline (Options::answer_wait).
  static bool timed(const Node& n) {
    return n.request.pending() && n.request.deadline() != Clock::time_point::max();
  }
  // Keeps the count of nodes whose pending request has a deadline right: called before `n`'s
  // request leaves that state.
  void leave_timed(const Node& n) {
    if (timed(n)) --timed_;
  }
  // What the node's pending request may change (downloads write; uploads only read).
  static RequestEffect effect_of(const Node& n);
  // Notes the master's request on a node the guard follows.
  static void note_request(Node& n, const can::Frame& frame);
  // True if `response` can answer the request `n` has pending.
  static bool can_answer(Node& n, const can::Frame& response);

  static can::Frame abort_for(canopen::NodeId node, const Node& n);
  // Whether the master of `n`'s pending request can still be waiting for its answer at `now`;
  // counts the abort dropped when it cannot.
  bool still_open(const Node& n, Clock::time_point now);
  // The node of an SDO request on the default server channel (0x601..0x67F), or 0.
  static canopen::NodeId request_node(const can::Frame& frame);

  Options options_;
  std::array<Node, 128> nodes_{};
  std::size_t timed_ = 0;  // nodes whose pending request has a deadline (timed())
  Counters counters_;
};

template <typename GatewayUp>
SdoLinkGuard::Verdict SdoLinkGuard::on_surface_frame(const can::Frame& frame,
                                                     GatewayUp&& gateway_up,
                                                     Clock::time_point now) {
  const canopen::NodeId node = request_node(frame);
  if (node == 0) return {};
  Node& n = nodes_[node];
  if (!n.owned) return {};
  const bool master_abort =
      frame.data[0] == 0x80 || (n.expect != Expect::block_download && frame.data[0] >> 5 == 4);
  leave_timed(n);      // if it waited, the master moved on (a newer request, or its own abort)
  if (master_abort) {  // nothing is in flight any more
    n.request.forget();
    n.expect = Expect::nothing;
    return {};
  }
  note_request(n, frame);
  if (!gateway_up(n.gateway)) {
    ++counters_.aborted_at_once;
    n.request.refused();
    n.expect = Expect::nothing;
    return {false, abort_for(node, n)};
  }
  n.withdrawn = false;
  // The end of a block upload gets no answer.
  if (n.expect == Expect::nothing) {
    n.request.clear();
  } else if (options_.answer_wait.count() > 0) {
    n.request.sent(now, effect_of(n), now + options_.answer_wait);
    ++timed_;
  } else {
    n.request.sent(now, effect_of(n));
  }
  return {};
}

}  // namespace canbridge::bridge
