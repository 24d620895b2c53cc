#include "routing/rpdop_relay.hpp"

#include <algorithm>
#include <stdexcept>
#include <utility>

namespace canbridge::bridge {

namespace pdop = canopen::pdop;
using pdop::AckStatus;

namespace {

bool valid_node(canopen::NodeId node) {
  return node >= 1 && node <= pdop::kMaxNode;
}

// What the master is sent for the gateway's `status` (see the header: a status the master cannot
// take as the end of its packet becomes 0x82).
AckStatus final_status(AckStatus status) {
  if (status == AckStatus::complete) return status;
  if (pdop::is_abort(status) && status != AckStatus::sender_abort) return status;
  return AckStatus::out_of_memory;
}

}  // namespace

std::vector<std::string> validate(const RpdopRelayOptions& o) {
  std::vector<std::string> problems;
  if (o.max_packet_bytes < 1 || o.max_packet_bytes > pdop::kMaxPacketBytes) {
    problems.push_back("max_packet_bytes: " + std::to_string(o.max_packet_bytes) +
                       " is outside 1..524280");
  }
  if (o.fragment_timeout < std::chrono::milliseconds{1} ||
      o.fragment_timeout > std::chrono::seconds{10}) {
    problems.push_back("fragment_timeout: " + std::to_string(o.fragment_timeout.count()) +
                       " ms is outside 1 ms..10 s");
  }
  if (o.window < 1) problems.push_back("window: 0 is outside 1..255");
  if (o.outcome_timeout < std::chrono::milliseconds{1} ||
      o.outcome_timeout > std::chrono::seconds{600}) {
    problems.push_back("outcome_timeout: " + std::to_string(o.outcome_timeout.count()) +
                       " ms is outside 1 ms..600 s");
  }
  return problems;
}

RpdopRelay::RpdopRelay(RpdopRelayOptions options) : options_(options) {
  const auto problems = validate(options_);
  if (!problems.empty()) throw std::invalid_argument("RPDOP relay: " + problems.front());
}

void RpdopRelay::set_relayed(NodeId node, bool relayed) {
  if (!valid_node(node) || relayed_[node] == relayed) return;
  relayed_[node] = relayed;
  if (relayed) return;
  for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) stream(node, rpdo) = Stream{};
  last_finished_[node].reset();
}

bool RpdopRelay::relayed(NodeId node) const {
  return valid_node(node) && relayed_[node];
}

bool RpdopRelay::on_frame(const can::Frame& frame, TimePoint now, Output& out) {
  if (frame.is_extended() || frame.is_error()) return false;
  if (frame.is_remote()) {
    // Remote frames are never fragments (section 2); on 0x681..0x69F they ask for acks (4.3).
    if (frame.id <= pdop::kAckBase || frame.id > pdop::kAckBase + pdop::kMaxNode) return false;
    const auto node = static_cast<NodeId>(frame.id - pdop::kAckBase);
    if (!relayed(node)) return false;
    expire(node, now, out);
    ++counters_.ack_requests;
    answer_request(node, out);
    return true;
  }
  const pdop::FragmentId id = pdop::decode(frame.id);
  const auto rpdo = pdop::rpdo_number(id.function_code);
  if (!rpdo || !relayed(id.node)) return false;
  expire(id.node, now, out);
  if (frame.len == 0 && !id.continued) {
    on_sender_abort(id.node, *rpdo, out);
  } else {
    on_fragment(id.node, *rpdo, id.toggle, id.continued, frame.payload(), now, out);
  }
  return true;
}

void RpdopRelay::on_outcome(std::uint64_t request_id, AckStatus status, Output& out) {
  // At most 124 streams, at most one outcome per packet: a scan costs less than an index would
  // allocate.
  for (NodeId node = 1; node <= pdop::kMaxNode; ++node) {
    if (!relayed_[node]) continue;
    for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
      const Stream& s = stream(node, rpdo);
      if (s.phase == Phase::forwarded && s.request_id == request_id) {
        end_forwarded(node, rpdo, status, out);
        return;
      }
    }
  }
  ++counters_.stale_outcomes;
}

void RpdopRelay::fail_forwarded(NodeId node, AckStatus status, Output& out) {
  if (node != 0 && !valid_node(node)) return;
  const NodeId first = node == 0 ? NodeId{1} : node;
  const NodeId last = node == 0 ? pdop::kMaxNode : node;
  for (NodeId n = first; n <= last; ++n) {
    if (!relayed_[n]) continue;
    for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
      if (stream(n, rpdo).phase == Phase::forwarded) end_forwarded(n, rpdo, status, out);
    }
  }
}

void RpdopRelay::tick(TimePoint now, Output& out) {
  for (NodeId node = 1; node <= pdop::kMaxNode; ++node) {
    if (relayed_[node]) expire(node, now, out);
  }
}

std::optional<RpdopRelay::TimePoint> RpdopRelay::next_deadline() const {
  std::optional<TimePoint> earliest;
  for (const Stream& s : streams_) {
    if (s.phase != Phase::receiving && s.phase != Phase::forwarded) continue;
    if (!earliest || s.deadline < *earliest) earliest = s.deadline;
  }
  return earliest;
}

void RpdopRelay::expire(NodeId node, TimePoint now, Output& out) {
  for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
    Stream& s = stream(node, rpdo);
    if (now < s.deadline) continue;
    if (s.phase == Phase::receiving) {
      // Kept open as aborted (section 4.3): a request learns 0x83, and the packet's stray
      // fragments cannot start another one.
      ++counters_.receiver_aborts;
      s.phase = Phase::aborted;
      s.abort_status = AckStatus::timeout;
      s.bytes.clear();
    } else if (s.phase == Phase::forwarded) {
      // The master is told now: it is waiting for this answer and would otherwise give up on
      // its own retries without knowing why.
      ++counters_.outcome_timeouts;
      finish(node, ack_of(node, rpdo, AckStatus::timeout), out);
    }
  }
}

void RpdopRelay::on_fragment(NodeId node, unsigned rpdo, bool toggle, bool continued,
                             std::span<const std::uint8_t> data, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  switch (s.phase) {
    case Phase::aborted:
      // Resynchronising (section 4.5): only a c = 0 frame ends the broken packet.
      ++counters_.dropped_fragments;
      if (!continued) {
        last_finished_[node] = ack_of(node, rpdo, s.abort_status);
        s.phase = Phase::idle;
      }
      return;
    case Phase::forwarded:
      // See the header: dropped unanswered, the packet's outcome still to come.
      ++counters_.dropped_fragments;
      return;
    case Phase::idle:
      s.received = 0;
      s.since_ack = 0;
      s.expected_toggle = false;
      s.bytes.clear();
      break;
    case Phase::receiving:
      break;
  }
  if (toggle != s.expected_toggle) {
    abort_packet(node, rpdo, AckStatus::toggle_error, continued, out);
    return;
  }
  if (continued && data.size() < pdop::kFragmentBytes) {
    abort_packet(node, rpdo, AckStatus::short_fragment, continued, out);
    return;
  }
  if (data.size() > options_.max_packet_bytes - s.bytes.size()) {
    abort_packet(node, rpdo, AckStatus::oversize, continued, out);
    return;
  }
  ++s.received;  // cannot wrap: max_packet_bytes allows at most 65,535 fragments
  if (!continued && s.received == 1) {
    // A one-frame packet (a plain RPDO): its own small vector, the stream's buffer untouched.
    forward(node, rpdo, std::vector<std::uint8_t>(data.begin(), data.end()), now, out);
    return;
  }
  if (s.received == 1) {
    const std::size_t want = std::min(options_.max_packet_bytes, kReserveBytes);
    if (s.bytes.capacity() < want) s.bytes.reserve(want);
  }
  s.bytes.insert(s.bytes.end(), data.begin(), data.end());
  s.expected_toggle = !s.expected_toggle;
  s.deadline = now + options_.fragment_timeout;
  s.phase = Phase::receiving;
  if (!continued) {
    forward(node, rpdo, std::exchange(s.bytes, {}), now, out);
    return;
  }
  if (++s.since_ack >= options_.window) {
    s.since_ack = 0;
    send(node, ack_of(node, rpdo, AckStatus::in_progress), out);
  }
}

void RpdopRelay::forward(NodeId node, unsigned rpdo, std::vector<std::uint8_t> bytes, TimePoint now,
                         Output& out) {
  Stream& s = stream(node, rpdo);
  s.phase = Phase::forwarded;
  s.request_id = next_request_id_++;
  s.deadline = now + options_.outcome_timeout;
  ++counters_.packets;
  out.packets.push_back(Packet{s.request_id, node, rpdo, std::move(bytes)});
}

void RpdopRelay::end_forwarded(NodeId node, unsigned rpdo, AckStatus status, Output& out) {
  const AckStatus sent = final_status(status);
  if (sent == AckStatus::complete) {
    ++counters_.completed;
  } else {
    ++counters_.failed;
  }
  finish(node, ack_of(node, rpdo, sent), out);
}

void RpdopRelay::on_sender_abort(NodeId node, unsigned rpdo, Output& out) {
  ++counters_.sender_aborts;
  // Confirmed whatever the state (section 4.4), also while forwarded: the packet's outcome, when
  // it comes, finds no forwarded packet and is stale.
  if (stream(node, rpdo).phase == Phase::idle) stream(node, rpdo).received = 0;
  finish(node, ack_of(node, rpdo, AckStatus::sender_abort), out);
}

void RpdopRelay::abort_packet(NodeId node, unsigned rpdo, AckStatus status, bool continued,
                              Output& out) {
  ++counters_.receiver_aborts;
  const pdop::Ack ack = ack_of(node, rpdo, status);
  if (!continued) {
    // The offending frame is itself the end-of-packet mark: nothing left to drop.
    finish(node, ack, out);
    return;
  }
  Stream& s = stream(node, rpdo);
  s.phase = Phase::aborted;
  s.abort_status = status;
  s.bytes.clear();
  send(node, ack, out);
}

void RpdopRelay::answer_request(NodeId node, Output& out) {
  bool any_open = false;
  for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
    Stream& s = stream(node, rpdo);
    switch (s.phase) {
      case Phase::receiving:
        // The master goes back to `received` on this answer, so the window counts from here.
        s.since_ack = 0;
        send(node, ack_of(node, rpdo, AckStatus::in_progress), out);
        any_open = true;
        break;
      case Phase::aborted:
        send(node, ack_of(node, rpdo, s.abort_status), out);
        any_open = true;
        break;
      case Phase::forwarded: {
        // Nothing left to send: wait (credit 0) until the node's outcome is known.
        pdop::Ack ack = ack_of(node, rpdo, AckStatus::in_progress);
        ack.credit = 0;
        send(node, ack, out);
        any_open = true;
        break;
      }
      case Phase::idle:
        break;
    }
  }
  if (!any_open && last_finished_[node]) send(node, *last_finished_[node], out);
}

void RpdopRelay::finish(NodeId node, const pdop::Ack& ack, Output& out) {
  Stream& s = stream(node, ack.rpdo);
  s.phase = Phase::idle;
  s.request_id = 0;
  s.bytes.clear();  // keeps the capacity for the next packet
  last_finished_[node] = ack;
  send(node, ack, out);
}

void RpdopRelay::send(NodeId node, const pdop::Ack& ack, Output& out) const {
  out.frames.push_back(pdop::encode_ack(node, ack));
}

pdop::Ack RpdopRelay::ack_of(NodeId node, unsigned rpdo, AckStatus status) const {
  // The relay takes fragments as fast as they come, so its credit is always its window.
  return pdop::Ack{static_cast<std::uint8_t>(rpdo), status, stream(node, rpdo).received,
                   options_.window};
}

}  // namespace canbridge::bridge
