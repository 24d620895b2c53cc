#include "sim/rpdop_receiver.hpp"

#include <stdexcept>
#include <utility>

namespace canbridge::sim {

namespace pdop = canopen::pdop;
using pdop::AckStatus;

namespace {

bool valid_node(canopen::NodeId node) {
  return node >= 1 && node <= pdop::kMaxNode;
}

}  // namespace

RpdopReceiver::RpdopReceiver(canopen::NodeId node, const PdopSpec& spec)
    : node_(node), spec_(spec) {
  if (!valid_node(node)) throw std::invalid_argument("PDOP node id must be 1..31");
  if (spec.max_packet_bytes < 1 || spec.max_packet_bytes > pdop::kMaxPacketBytes) {
    throw std::invalid_argument("PDOP max_packet_bytes must be 1..524280");
  }
  if (spec.fragment_timeout < std::chrono::milliseconds{1} ||
      spec.fragment_timeout > std::chrono::seconds{10}) {
    throw std::invalid_argument("PDOP fragment_timeout must be 1 ms..10 s");
  }
  if (spec.window < 1) throw std::invalid_argument("PDOP window must be 1..255");
}

bool RpdopReceiver::set_node_id(canopen::NodeId node) {
  if (!valid_node(node)) return false;
  node_ = node;
  reset();
  return true;
}

void RpdopReceiver::reset() {
  for (Stream& s : streams_) s = Stream{};
  last_finished_.reset();
}

bool RpdopReceiver::on_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out,
                             std::vector<Packet>& completed) {
  if (frame.is_extended() || frame.is_error()) return false;
  if (frame.id == pdop::ack_cob_id(node_)) {
    // Our own acknowledgements use this identifier too; only the request is ours to answer.
    if (!frame.is_remote()) return false;
    poll(now);
    ++counters_.ack_requests;
    answer_ack_request(out);
    return true;
  }
  if (frame.is_remote()) return false;  // remote frames are never fragments (section 2)
  const pdop::FragmentId id = pdop::decode(frame.id);
  const auto rpdo = pdop::rpdo_number(id.function_code);
  if (!rpdo || id.node != node_) return false;
  poll(now);
  if (frame.len == 0 && !id.continued) {
    on_sender_abort(*rpdo, out);
  } else {
    on_fragment(*rpdo, id.toggle, id.continued, frame.payload(), now, out, completed);
  }
  return true;
}

void RpdopReceiver::poll(TimePoint now) {
  for (Stream& s : streams_) {
    if (s.phase != Phase::receiving || now < s.deadline) continue;
    // Kept open as aborted, so that a request learns 0x83 and stray fragments of the packet
    // cannot start another one.
    ++counters_.timeouts;
    s.phase = Phase::aborted;
    s.abort_status = AckStatus::timeout;
    s.bytes.clear();
  }
}

RpdopReceiver::TimePoint RpdopReceiver::next_deadline() const {
  TimePoint earliest = TimePoint::max();
  for (const Stream& s : streams_) {
    if (s.phase == Phase::receiving && s.deadline < earliest) earliest = s.deadline;
  }
  return earliest;
}

void RpdopReceiver::on_fragment(unsigned rpdo, bool toggle, bool continued,
                                std::span<const std::uint8_t> data, TimePoint now,
                                std::vector<can::Frame>& out, std::vector<Packet>& completed) {
  Stream& s = stream(rpdo);
  if (s.phase == Phase::aborted) {
    // Resynchronising (section 4.4): only a c = 0 frame ends the broken packet.
    ++counters_.dropped_fragments;
    if (!continued) {
      s.phase = Phase::idle;
      last_finished_ = ack_of(rpdo, s.abort_status);
    }
    return;
  }
  if (s.phase == Phase::idle) s = Stream{};
  if (toggle != s.expected_toggle) {
    ++counters_.toggle_errors;
    abort_packet(rpdo, AckStatus::toggle_error, continued, out);
    return;
  }
  if (continued && data.size() < pdop::kFragmentBytes) {
    ++counters_.short_fragments;
    abort_packet(rpdo, AckStatus::short_fragment, continued, out);
    return;
  }
  if (data.size() > spec_.max_packet_bytes - s.bytes.size()) {
    ++counters_.oversize;
    abort_packet(rpdo, AckStatus::oversize, continued, out);
    return;
  }
  s.bytes.insert(s.bytes.end(), data.begin(), data.end());
  ++s.received;  // cannot wrap: max_packet_bytes allows at most 65,535 fragments
  ++s.since_ack;
  s.expected_toggle = !s.expected_toggle;
  s.deadline = now + spec_.fragment_timeout;
  s.phase = Phase::receiving;
  if (!continued) {
    ++counters_.packets;
    completed.push_back(Packet{rpdo, std::move(s.bytes)});
    finish(ack_of(rpdo, AckStatus::complete), out);
    return;
  }
  if (s.since_ack >= spec_.window) {
    s.since_ack = 0;
    send(ack_of(rpdo, AckStatus::in_progress), out);
  }
}

void RpdopReceiver::on_sender_abort(unsigned rpdo, std::vector<can::Frame>& out) {
  ++counters_.sender_aborts;
  // Confirmed whatever the state, so that a sender whose earlier acknowledgement was lost learns
  // that the node is ready for a new packet.
  if (stream(rpdo).phase == Phase::idle) stream(rpdo).received = 0;
  finish(ack_of(rpdo, AckStatus::sender_abort), out);
}

void RpdopReceiver::abort_packet(unsigned rpdo, AckStatus status, bool continued,
                                 std::vector<can::Frame>& out) {
  Stream& s = stream(rpdo);
  const pdop::Ack ack = ack_of(rpdo, status);
  if (!continued) {
    // The offending frame is itself the end-of-packet mark: nothing left to drop.
    finish(ack, out);
    return;
  }
  s.phase = Phase::aborted;
  s.abort_status = status;
  s.bytes.clear();
  send(ack, out);
}

void RpdopReceiver::answer_ack_request(std::vector<can::Frame>& out) {
  bool any_open = false;
  for (unsigned rpdo = 1; rpdo <= streams_.size(); ++rpdo) {
    Stream& s = stream(rpdo);
    if (s.phase == Phase::receiving) {
      // The master goes back to `received` on this answer, so the window counts from here.
      s.since_ack = 0;
      send(ack_of(rpdo, AckStatus::in_progress), out);
      any_open = true;
    } else if (s.phase == Phase::aborted) {
      send(ack_of(rpdo, s.abort_status), out);
      any_open = true;
    }
  }
  if (!any_open && last_finished_) send(*last_finished_, out);
}

void RpdopReceiver::send(const pdop::Ack& ack, std::vector<can::Frame>& out) const {
  out.push_back(pdop::encode_ack(node_, ack));
}

void RpdopReceiver::finish(const pdop::Ack& ack, std::vector<can::Frame>& out) {
  Stream& s = stream(ack.rpdo);
  s.phase = Phase::idle;
  s.bytes.clear();
  last_finished_ = ack;
  send(ack, out);
}

pdop::Ack RpdopReceiver::ack_of(unsigned rpdo, AckStatus status) const {
  // The simulated node takes fragments as they come, so its credit is always its whole FIFO.
  return pdop::Ack{static_cast<std::uint8_t>(rpdo), status, stream(rpdo).received, spec_.window};
}

}  // namespace canbridge::sim
