#include "bridge/sdo_link_guard.hpp"

namespace canbridge::bridge {

canopen::NodeId SdoLinkGuard::request_node(const can::Frame& frame) {
  if (frame.is_extended() || frame.is_remote() || frame.len != 8) return 0;
  if (frame.id <= canopen::cob::sdo_rx || frame.id > canopen::cob::sdo_rx + canopen::kMaxNodeId) {
    return 0;
  }
  return static_cast<canopen::NodeId>(frame.id - canopen::cob::sdo_rx);
}

can::Frame SdoLinkGuard::abort_for(canopen::NodeId node, const Node& n) {
  return can::Frame::standard(
      canopen::cob::sdo_tx + node,
      {0x80, n.mux[0], n.mux[1], n.mux[2], static_cast<std::uint8_t>(kLinkDownAbort),
       static_cast<std::uint8_t>(kLinkDownAbort >> 8),
       static_cast<std::uint8_t>(kLinkDownAbort >> 16),
       static_cast<std::uint8_t>(kLinkDownAbort >> 24)});
}

RequestEffect SdoLinkGuard::effect_of(const Node& n) {
  switch (n.expect) {
    case Expect::download_initiate:
    case Expect::download_segment:
    case Expect::block_download_initiate:
    case Expect::block_download:
      return RequestEffect::changes_node;
    default:
      return RequestEffect::none;
  }
}

void SdoLinkGuard::note_request(Node& n, const can::Frame& frame) {
  const std::uint8_t first = frame.data[0];
  // Inside a block download sub-block every master frame is a segment (its first byte a
  // sequence number): the transfer goes on, nothing to note.
  if (n.expect == Expect::block_download) return;
  const auto note_object = [&] {
    n.mux[0] = frame.data[1];
    n.mux[1] = frame.data[2];
    n.mux[2] = frame.data[3];
  };
  switch (first >> 5) {
    case 0:  // download segment
      n.expect = Expect::download_segment;
      n.toggle = first & 0x10;
      return;
    case 1:
      note_object();
      n.expect = Expect::download_initiate;
      return;
    case 2:
      note_object();
      n.expect = Expect::upload_initiate;
      return;
    case 3:  // upload segment
      n.expect = Expect::upload_segment;
      n.toggle = first & 0x10;
      return;
    case 5:  // block upload: initiate, start (3), acknowledge a sub-block (2), end (1)
      switch (first & 0x03) {
        case 0:
          note_object();
          n.expect = Expect::block_upload_initiate;
          return;
        case 1:
          n.expect = Expect::nothing;  // the server does not answer the end
          return;
        default:
          n.expect = Expect::block_upload;
          return;
      }
    case 6:  // block download: initiate (cs 0); the end request (cs 1) follows the last ack
      if ((first & 0x01) == 0) {
        note_object();
        n.expect = Expect::block_download_initiate;
      } else {
        n.expect = Expect::block_download;
      }
      return;
    default:  // not a valid request: the server's abort answers it
      n.expect = Expect::untracked;
      return;
  }
}

bool SdoLinkGuard::can_answer(Node& n, const can::Frame& response) {
  const std::uint8_t first = response.data[0];
  const std::uint8_t scs = first >> 5;
  const bool same_object =
      response.data[1] == n.mux[0] && response.data[2] == n.mux[1] && response.data[3] == n.mux[2];
  switch (n.expect) {
    case Expect::untracked:
    // Nothing pending, the last request answered: an answer to a master on the module bus
    // (transparency); the late answer to an aborted request was dropped before.
    case Expect::nothing:
      return true;
    case Expect::block_upload:  // segments: any first byte
      return true;
    default:
      break;
  }
  // An abort ends the transfer it names (CiA 301: the multiplexer of the transfer; some servers
  // send none). One naming another object answers an older request, executed just before a cut
  // and aborted toward the master: passed on, it would end the master's pending request with an
  // answer the master cannot place (issue 27).
  if (first == 0x80) {
    const bool names_none = response.data[1] == 0 && response.data[2] == 0 && response.data[3] == 0;
    if (!same_object && !names_none) return false;
    n.expect = Expect::nothing;
    return true;
  }
  switch (n.expect) {
    case Expect::download_initiate:
      return scs == 3 && same_object;
    case Expect::upload_initiate:
      return scs == 2 && same_object;
    case Expect::download_segment:
      return scs == 1 && (first & 0x10) == n.toggle;
    case Expect::upload_segment:
      return scs == 0 && (first & 0x10) == n.toggle;
    case Expect::block_download_initiate:
      if (scs != 5 || (first & 0x03) != 0 || !same_object) return false;
      n.expect = Expect::block_download;
      return true;
    case Expect::block_upload_initiate:
      if (scs == 2 && same_object) {  // the server switched to the upload protocol
        n.expect = Expect::upload_initiate;
        return true;
      }
      if (scs != 6 || (first & 0x01) != 0 || !same_object) return false;  // ss: bit 0
      n.expect = Expect::block_upload;
      return true;
    case Expect::block_download:  // sub-block acknowledgements, the end response
      if (scs != 5) return false;
      if ((first & 0x03) == 1) n.expect = Expect::nothing;
      return true;
    default:
      return false;
  }
}

bool SdoLinkGuard::on_gateway_frame(GatewayId gateway, const can::Frame& frame) {
  if (frame.is_extended()) return true;
  const auto address = canopen::split_predefined(frame.id);
  if (!address || address->node == 0) return true;
  Node& n = nodes_[address->node];
  n.owned = true;
  n.gateway = gateway;
  if (address->function_base != canopen::cob::sdo_tx) return true;
  if (n.request.told()) {
    ++counters_.late_responses_dropped;
    return false;
  }
  if (!can_answer(n, frame)) {
    ++counters_.stale_responses_dropped;
    return false;
  }
  // Executed before the cut, its answer brought by the next link.
  leave_timed(n);
  if (n.request.answered() == RequestLife::Answer::recovered) ++counters_.answers_recovered;
  // A step answered: nothing more may come, except inside block transfers.
  if (n.expect != Expect::block_download && n.expect != Expect::block_upload &&
      n.expect != Expect::untracked) {
    n.expect = Expect::nothing;
  }
  return true;
}

void SdoLinkGuard::note_owner(GatewayId gateway, canopen::NodeId node) {
  if (node == 0 || node > canopen::kMaxNodeId) return;
  nodes_[node].owned = true;
  nodes_[node].gateway = gateway;
}

void SdoLinkGuard::note_claims(GatewayId gateway, const GatewayClaims& claims) {
  for (const ModuleClaim& m : claims.modules) {
    for (canopen::NodeId node : m.surface_nodes) note_owner(gateway, node);
  }
}

std::optional<can::Frame> SdoLinkGuard::on_not_forwarded(const can::Frame& frame) {
  const canopen::NodeId node = request_node(frame);
  if (node == 0 || frame.data[0] >> 5 == 4) return std::nullopt;  // not a request, or an abort
  Node& n = nodes_[node];
  leave_timed(n);
  n.request.refused();
  n.expect = Expect::nothing;
  ++counters_.aborted_not_forwarded;
  return abort_for(node, n);
}

void SdoLinkGuard::on_request_withdrawn(const can::Frame& request) {
  const canopen::NodeId node = request_node(request);
  if (node == 0) return;
  Node& n = nodes_[node];
  if (!n.owned) {
    ++counters_.withdrawn_untracked;
    return;
  }
  // Only the master's last request to a node can be pending: one withdrawn request per pending
  // node stands for it, any other was given up by its master when it sent a newer one.
  if (n.request.pending() && !n.withdrawn) {
    n.withdrawn = true;
    ++counters_.withdrawn_pending;
    return;
  }
  ++counters_.withdrawn_answered_before;
}

bool SdoLinkGuard::still_open(const Node& n, Clock::time_point now) {
  if (n.request.asker_still_waits(now, options_.transfer_open_for)) return true;
  ++counters_.stale_aborts_dropped;
  return false;
}

std::optional<can::Frame> SdoLinkGuard::abort_unanswered(canopen::NodeId node, Node& n,
                                                         Clock::time_point now,
                                                         std::uint64_t& aborted) {
  leave_timed(n);
  // Aborted either way: a late answer to it must not reach the master any more than the abort
  // may. The one abort code says the same as the master's own time-out would: the request may
  // have run (the end RequestLife decides is timed out or outcome unknown).
  n.request.end_unanswered(MayHaveRun::yes);
  n.expect = Expect::nothing;
  if (!still_open(n, now)) return std::nullopt;
  ++aborted;
  return abort_for(node, n);
}

std::vector<can::Frame> SdoLinkGuard::on_gateway_down(GatewayId gateway, Clock::time_point now) {
  std::vector<can::Frame> aborts;
  for (canopen::NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
    Node& n = nodes_[node];
    if (!n.owned || n.gateway != gateway || !n.request.pending()) continue;
    // The request may have reached the gateway before the cut: its answer waits there, in the
    // gateway's reliable stream, and crosses once a new link resumes it, until the deadline the
    // request has had since it was sent (Options::answer_wait; without one, none waits).
    if (timed(n) && !n.request.due(now)) {
      n.request.await_answer(n.request.deadline());
      continue;
    }
    if (auto abort = abort_unanswered(node, n, now, counters_.aborted_in_flight)) {
      aborts.push_back(*abort);
    }
  }
  return aborts;
}

std::optional<SdoLinkGuard::Clock::time_point> SdoLinkGuard::next_deadline() const {
  if (timed_ == 0) return std::nullopt;
  std::optional<Clock::time_point> earliest;
  for (const Node& n : nodes_) {
    if (!timed(n)) continue;
    const Clock::time_point due = n.request.deadline();
    if (!earliest || due < *earliest) earliest = due;
  }
  return earliest;
}

std::vector<can::Frame> SdoLinkGuard::on_gateway_restart(GatewayId gateway, Clock::time_point now) {
  std::vector<can::Frame> aborts;
  if (timed_ == 0) return aborts;
  for (canopen::NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
    Node& n = nodes_[node];
    if (!n.request.awaiting() || n.gateway != gateway) continue;
    if (auto abort = abort_unanswered(node, n, now, counters_.aborted_in_flight)) {
      aborts.push_back(*abort);
    }
  }
  return aborts;
}

std::vector<can::Frame> SdoLinkGuard::on_time(Clock::time_point now, const Withdraw& withdraw) {
  std::vector<can::Frame> aborts;
  if (timed_ == 0) return aborts;
  for (canopen::NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
    Node& n = nodes_[node];
    if (!timed(n) || !n.request.due(now)) continue;
    // Awaiting: its link was lost, and it was withdrawn then (Surface::on_gateway_down). Else
    // overdue on a live link: lost on the line (and given up by the gateway's stream), still on
    // its way, or never answered by its node; withdrawn now.
    const bool link_lost = n.request.awaiting();
    if (!link_lost && withdraw) withdraw(node);
    if (auto abort = abort_unanswered(
            node, n, now, link_lost ? counters_.aborted_in_flight : counters_.aborted_overdue)) {
      aborts.push_back(*abort);
    }
  }
  return aborts;
}

std::optional<can::Frame> SdoLinkGuard::on_request_discarded(const can::Frame& request,
                                                             Clock::time_point now) {
  const canopen::NodeId node = request_node(request);
  if (node == 0) return std::nullopt;
  const std::uint8_t command = request.data[0] >> 5;
  if (command == 4) return std::nullopt;  // the master's own abort needs no answer
  Node& n = nodes_[node];
  if (n.owned && !n.request.pending()) return std::nullopt;  // answered already
  leave_timed(n);
  Node answer = n;
  if (!n.owned && (command == 1 || command == 2 || command == 5 || command == 6)) {
    answer.mux[0] = request.data[1];
    answer.mux[1] = request.data[2];
    answer.mux[2] = request.data[3];
  }
  if (n.owned) {
    // Given up by the backbone after it left the surface, or with the process it went to.
    n.request.end_unanswered(MayHaveRun::yes);
    n.expect = Expect::nothing;
  } else {
    n.request.clear();
  }
  if (n.owned && !still_open(n, now)) return std::nullopt;
  ++counters_.aborted_discarded;
  return abort_for(node, answer);
}

std::optional<SdoLinkGuard::GatewayId> SdoLinkGuard::owner_of(canopen::NodeId node) const {
  if (node == 0 || node > canopen::kMaxNodeId || !nodes_[node].owned) return std::nullopt;
  return nodes_[node].gateway;
}

}  // namespace canbridge::bridge
