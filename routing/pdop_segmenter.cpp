#include "routing/pdop_segmenter.hpp"

#include <algorithm>
#include <cstdio>
#include <span>
#include <stdexcept>
#include <utility>

namespace canbridge::bridge {

namespace pdop = canopen::pdop;
using pdop::AckStatus;

namespace {

constexpr std::size_t kMaxQueuePerRpdo = 1024;
constexpr std::size_t kMaxHeldBytes = std::size_t{1} << 30;

bool valid_address(NodeId node, unsigned rpdo) {
  return node >= 1 && node <= pdop::kMaxNode && rpdo >= 1 && rpdo <= 4;
}

std::uint32_t fragment_count(std::size_t bytes) {
  return static_cast<std::uint32_t>((bytes + pdop::kFragmentBytes - 1) / pdop::kFragmentBytes);
}

// Fragment k of `bytes` (docs/pdop.md section 2), built when it is sent: the same frame
// pdop::fragment() puts at index k.
can::Frame fragment_frame(NodeId node, unsigned rpdo, const std::vector<std::uint8_t>& bytes,
                          std::uint32_t k, std::uint32_t count) {
  const pdop::FragmentId id{static_cast<std::uint8_t>(pdop::rpdo_base(rpdo) >> 7), k % 2 == 1,
                            k + 1 < count, node};
  const std::size_t offset = std::size_t{k} * pdop::kFragmentBytes;
  const std::size_t length = std::min(pdop::kFragmentBytes, bytes.size() - offset);
  return can::Frame::from_span(pdop::encode(id),
                               std::span<const std::uint8_t>(bytes).subspan(offset, length));
}

}  // namespace

std::vector<std::string> validate(const PdopSegmenterOptions& o) {
  std::vector<std::string> problems;
  if (o.max_packet_bytes < 1 || o.max_packet_bytes > pdop::kMaxPacketBytes) {
    problems.push_back("max_packet_bytes: " + std::to_string(o.max_packet_bytes) +
                       " is outside 1..524280");
  }
  if (o.window < 1) problems.push_back("window: 0 is outside 1..255");
  if (o.ack_timeout < std::chrono::milliseconds{1} || o.ack_timeout > std::chrono::seconds{10}) {
    problems.push_back("ack_timeout: " + std::to_string(o.ack_timeout.count()) +
                       " ms is outside 1 ms..10 s");
  }
  if (o.retries > 10) {
    problems.push_back("retries: " + std::to_string(o.retries) + " is outside 0..10");
  }
  if (o.queue_per_rpdo > kMaxQueuePerRpdo) {
    problems.push_back("queue_per_rpdo: " + std::to_string(o.queue_per_rpdo) +
                       " is outside 0..1024");
  }
  if (o.max_held_bytes < o.max_packet_bytes || o.max_held_bytes > kMaxHeldBytes) {
    problems.push_back("max_held_bytes: " + std::to_string(o.max_held_bytes) +
                       " is outside max_packet_bytes (" + std::to_string(o.max_packet_bytes) +
                       ")..1073741824");
  }
  return problems;
}

const char* to_string(PdopResult result) {
  switch (result) {
    case PdopResult::complete:
      return "complete";
    case PdopResult::receiver_abort:
      return "receiver_abort";
    case PdopResult::timeout:
      return "timeout";
    case PdopResult::cancelled:
      return "cancelled";
    case PdopResult::refused_busy:
      return "refused_busy";
    case PdopResult::refused_size:
      return "refused_size";
    case PdopResult::refused_address:
      return "refused_address";
  }
  return "?";
}

std::string to_string(const PdopOutcome& o) {
  char text[200];
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(o.elapsed).count();
  std::string result = to_string(o.result);
  if (o.result == PdopResult::receiver_abort) {
    char code[8];
    std::snprintf(code, sizeof code, " 0x%02X", static_cast<unsigned>(o.status));
    result += code;
  }
  std::snprintf(text, sizeof text,
                "request %llu node %u RPDO%u: %s (%u fragments, %u sent, %u again, %u request%s, "
                "%lld ms)",
                static_cast<unsigned long long>(o.request_id), static_cast<unsigned>(o.node),
                o.rpdo, result.c_str(), o.fragments, o.fragments_sent, o.retransmissions,
                o.ack_requests, o.ack_requests == 1 ? "" : "s", static_cast<long long>(ms));
  return text;
}

PdopSegmenter::PdopSegmenter(PdopSegmenterOptions options)
    : options_(options), ack_timeout_(std::chrono::duration_cast<Duration>(options.ack_timeout)) {
  const auto problems = validate(options_);
  if (!problems.empty()) throw std::invalid_argument("PDOP segmenter: " + problems.front());
}

void PdopSegmenter::submit(NodeId node, unsigned rpdo, std::vector<std::uint8_t> packet,
                           std::uint64_t request_id, TimePoint now, Output& out) {
  ++counters_.submitted;
  if (!valid_address(node, rpdo)) {
    refuse(node, rpdo, PdopResult::refused_address, request_id, out);
    return;
  }
  if (packet.empty() || packet.size() > options_.max_packet_bytes) {
    refuse(node, rpdo, PdopResult::refused_size, request_id, out);
    return;
  }
  Stream& s = stream(node, rpdo);
  const bool free = s.phase == Phase::idle && s.waiting.empty();
  if ((!free && s.waiting.size() >= options_.queue_per_rpdo) ||
      packet.size() > options_.max_held_bytes - held_bytes_) {
    refuse(node, rpdo, PdopResult::refused_busy, request_id, out);
    return;
  }
  held_bytes_ += packet.size();
  s.waiting.push_back(Request{request_id, std::move(packet), now});
  try_start(node, rpdo, now, out);
}

bool PdopSegmenter::on_frame(const can::Frame& frame, TimePoint now, Output& out) {
  if (frame.id <= pdop::kAckBase || frame.id > pdop::kAckBase + pdop::kMaxNode) return false;
  const auto ack = pdop::decode_ack(frame);
  if (!ack) return false;
  on_ack(static_cast<NodeId>(frame.id & 0x1Fu), *ack, now, out);
  return true;
}

void PdopSegmenter::on_ack(NodeId node, const pdop::Ack& ack, TimePoint now, Output& out) {
  const unsigned rpdo = ack.rpdo;
  Stream& s = stream(node, rpdo);
  const auto raw = static_cast<std::uint8_t>(ack.status);
  if (s.phase == Phase::resync) {
    // Everything before the node's 0x85 is about the aborted packet.
    if (ack.status != AckStatus::sender_abort) {
      ++counters_.ignored_acks;
      return;
    }
    ++counters_.acks;
    s.phase = Phase::idle;
    s.abort_first = false;
    set_deadline(s, TimePoint::max());
    try_start(node, rpdo, now, out);
    return;
  }
  // 0x85 confirms an abort frame this segmenter is no longer waiting for (section 4.4); codes
  // 2..0x7F are not defined.
  if (s.phase != Phase::sending || ack.status == AckStatus::sender_abort ||
      (raw > static_cast<std::uint8_t>(AckStatus::complete) && !pdop::is_abort(ack.status))) {
    ++counters_.ignored_acks;
    return;
  }
  // Within a packet the node's count only grows and never passes what was sent: anything else
  // is about another packet (e.g. the one before, section 4.3) or older than what we know.
  if (ack.received < s.acked || ack.received > s.sent_high) {
    ++counters_.ignored_acks;
    return;
  }
  if (pdop::is_abort(ack.status)) {
    ++counters_.acks;
    finish(node, rpdo, PdopResult::receiver_abort, ack.status, now, out);
    begin_resync(node, rpdo, now, out);
    return;
  }
  if (ack.status == AckStatus::complete) {
    // Counted only for a packet whose last fragment was sent, with all of it (section 4.2).
    if (s.sent_high != s.fragments || ack.received != s.fragments) {
      ++counters_.ignored_acks;
      return;
    }
    ++counters_.acks;
    finish(node, rpdo, PdopResult::complete, AckStatus::complete, now, out);
    try_start(node, rpdo, now, out);
    return;
  }
  if (ack.received == s.fragments && s.sent_high == s.fragments && s.awaiting_answer) {
    // Every fragment taken, not complete yet: a store-and-forward receiver (the surface's relay)
    // waiting for the node's own outcome answers a request so, with credit 0 (docs/pdop.md 4.3).
    // An answer, not progress: nothing to send, and the next request after ack_timeout.
    ++counters_.acks;
    s.acked = ack.received;
    s.awaiting_answer = false;
    s.unanswered = 0;
    s.limit = s.fragments;
    set_deadline(s, now + ack_timeout_);
    return;
  }
  if (ack.received >= s.fragments) {  // the node would have completed it
    ++counters_.ignored_acks;
    return;
  }
  ++counters_.acks;
  s.acked = ack.received;
  if (s.awaiting_answer) {
    // The first acknowledgement after a request: the node expects fragment `received` next.
    s.next = ack.received;
    s.awaiting_answer = false;
    s.unanswered = 0;
  }
  s.limit = std::uint32_t{ack.received} + ack.credit;
  set_deadline(s, now + ack_timeout_);
  send_window(node, rpdo, now, out);
}

void PdopSegmenter::tick(TimePoint now, Output& out) {
  if (earliest_dirty_) {
    earliest_ = scan_earliest();
    earliest_dirty_ = false;
  }
  if (earliest_ > now) return;
  for (NodeId node = 1; node <= pdop::kMaxNode; ++node) {
    for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
      if (stream(node, rpdo).deadline <= now) on_timeout(node, rpdo, now, out);
    }
  }
}

std::optional<PdopSegmenter::TimePoint> PdopSegmenter::next_deadline() const {
  if (earliest_dirty_) {
    earliest_ = scan_earliest();
    earliest_dirty_ = false;
  }
  if (earliest_ == TimePoint::max()) return std::nullopt;
  return earliest_;
}

void PdopSegmenter::on_timeout(NodeId node, unsigned rpdo, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  switch (s.phase) {
    case Phase::idle:  // the node's request hold has passed
      try_start(node, rpdo, now, out);
      return;
    case Phase::sending:
      if (s.unanswered >= options_.retries) {
        finish(node, rpdo, PdopResult::timeout, AckStatus::in_progress, now, out);
        begin_resync(node, rpdo, now, out);
      } else {
        send_request(node, rpdo, now, out);
      }
      return;
    case Phase::resync:
      if (s.abort_sends <= options_.retries) {
        send_abort(node, rpdo, out);
        ++s.abort_sends;
        set_deadline(s, now + ack_timeout_);
        return;
      }
      // The node does not confirm: go on, but abort again before the next packet.
      ++counters_.resync_gave_up;
      s.phase = Phase::idle;
      s.abort_first = true;
      set_deadline(s, TimePoint::max());
      try_start(node, rpdo, now, out);
      return;
  }
}

bool PdopSegmenter::cancel(std::uint64_t request_id, TimePoint now, Output& out) {
  for (NodeId node = 1; node <= pdop::kMaxNode; ++node) {
    for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
      Stream& s = stream(node, rpdo);
      if (s.phase == Phase::sending && s.request.id == request_id) {
        finish(node, rpdo, PdopResult::cancelled, AckStatus::in_progress, now, out);
        begin_resync(node, rpdo, now, out);
        return true;
      }
      const auto it = std::find_if(s.waiting.begin(), s.waiting.end(),
                                   [&](const Request& r) { return r.id == request_id; });
      if (it == s.waiting.end()) continue;
      PdopOutcome o;
      o.request_id = request_id;
      o.node = node;
      o.rpdo = rpdo;
      o.result = PdopResult::cancelled;
      o.fragments = fragment_count(it->bytes.size());
      o.elapsed = now - it->submitted;
      held_bytes_ -= it->bytes.size();
      s.waiting.erase(it);
      ++counters_.cancelled;
      out.outcomes.push_back(o);
      if (s.phase == Phase::idle && s.waiting.empty()) set_deadline(s, TimePoint::max());
      return true;
    }
  }
  return false;
}

std::size_t PdopSegmenter::cancel_node(NodeId node, TimePoint now, Output& out) {
  if (node < 1 || node > pdop::kMaxNode) return 0;
  std::size_t count = 0;
  for (unsigned rpdo = 1; rpdo <= kRpdos; ++rpdo) {
    Stream& s = stream(node, rpdo);
    if (s.phase == Phase::sending) {
      finish(node, rpdo, PdopResult::cancelled, AckStatus::in_progress, now, out);
      begin_resync(node, rpdo, now, out);
      ++count;
    }
    while (!s.waiting.empty()) {
      cancel(s.waiting.front().id, now, out);
      ++count;
    }
  }
  return count;
}

std::optional<std::uint64_t> PdopSegmenter::active_request(NodeId node, unsigned rpdo) const {
  if (!valid_address(node, rpdo)) return std::nullopt;
  const Stream& s = stream(node, rpdo);
  if (s.phase != Phase::sending) return std::nullopt;
  return s.request.id;
}

std::size_t PdopSegmenter::queued(NodeId node, unsigned rpdo) const {
  return valid_address(node, rpdo) ? stream(node, rpdo).waiting.size() : 0;
}

void PdopSegmenter::try_start(NodeId node, unsigned rpdo, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  if (s.phase != Phase::idle) return;
  if (s.waiting.empty()) {
    set_deadline(s, TimePoint::max());
    return;
  }
  if (now < hold_until_[node]) {
    // A request to this node is being answered; its answer could name the packet before.
    set_deadline(s, hold_until_[node]);
    return;
  }
  s.request = std::move(s.waiting.front());
  s.waiting.pop_front();
  s.phase = Phase::sending;
  s.fragments = fragment_count(s.request.bytes.size());
  s.next = 0;
  s.limit = options_.window;
  s.sent_high = 0;
  s.acked = 0;
  s.fragments_sent = 0;
  s.retransmissions = 0;
  s.requests = 0;
  s.unanswered = 0;
  s.awaiting_answer = false;
  if (s.abort_first) {
    send_abort(node, rpdo, out);
    s.abort_first = false;
  }
  send_window(node, rpdo, now, out);
}

void PdopSegmenter::send_window(NodeId node, unsigned rpdo, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  const std::uint32_t end = std::min(s.limit, s.fragments);
  if (s.next >= end) return;
  for (; s.next < end; ++s.next) {
    out.frames.push_back(fragment_frame(node, rpdo, s.request.bytes, s.next, s.fragments));
    if (s.next < s.sent_high) {
      ++s.retransmissions;
      ++counters_.retransmissions;
    }
    ++s.fragments_sent;
    ++counters_.fragments_sent;
  }
  s.sent_high = std::max(s.sent_high, s.next);
  set_deadline(s, now + ack_timeout_);
}

void PdopSegmenter::send_request(NodeId node, unsigned rpdo, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  // One remote frame per node and instant: the node answers for all of its RPDOs.
  if (last_request_[node] != now) {
    out.frames.push_back(pdop::ack_request(node));
    ++counters_.ack_requests;
    last_request_[node] = now;
  }
  ++s.requests;
  ++s.unanswered;
  s.awaiting_answer = true;
  hold_until_[node] = std::max(hold_until_[node], now + ack_timeout_);
  set_deadline(s, now + ack_timeout_);
}

void PdopSegmenter::send_abort(NodeId node, unsigned rpdo, Output& out) {
  out.frames.push_back(pdop::abort_frame(pdop::rpdo_base(rpdo), node));
  ++counters_.abort_frames;
}

void PdopSegmenter::begin_resync(NodeId node, unsigned rpdo, TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  send_abort(node, rpdo, out);
  s.phase = Phase::resync;
  s.abort_sends = 1;
  s.abort_first = false;
  set_deadline(s, now + ack_timeout_);
}

void PdopSegmenter::finish(NodeId node, unsigned rpdo, PdopResult result, AckStatus status,
                           TimePoint now, Output& out) {
  Stream& s = stream(node, rpdo);
  PdopOutcome o;
  o.request_id = s.request.id;
  o.node = node;
  o.rpdo = rpdo;
  o.result = result;
  o.status = status;
  o.fragments = s.fragments;
  o.fragments_sent = s.fragments_sent;
  o.retransmissions = s.retransmissions;
  o.ack_requests = s.requests;
  o.elapsed = now - s.request.submitted;
  out.outcomes.push_back(o);
  switch (result) {
    case PdopResult::complete:
      ++counters_.complete;
      break;
    case PdopResult::receiver_abort:
      ++counters_.receiver_aborts;
      break;
    case PdopResult::timeout:
      ++counters_.timeouts;
      break;
    default:
      ++counters_.cancelled;
      break;
  }
  held_bytes_ -= s.request.bytes.size();
  s.request = Request{};  // frees the bytes
  s.phase = Phase::idle;
  s.awaiting_answer = false;
  set_deadline(s, TimePoint::max());
}

void PdopSegmenter::refuse(NodeId node, unsigned rpdo, PdopResult result, std::uint64_t request_id,
                           Output& out) {
  ++counters_.refused;
  PdopOutcome o;
  o.request_id = request_id;
  o.node = node;
  o.rpdo = rpdo;
  o.result = result;
  out.outcomes.push_back(o);
}

void PdopSegmenter::set_deadline(Stream& s, TimePoint deadline) {
  if (deadline == s.deadline) return;
  if (!earliest_dirty_) {
    if (deadline < earliest_) {
      earliest_ = deadline;
    } else if (s.deadline == earliest_) {
      earliest_dirty_ = true;  // the earliest moved later: one scan when next asked
    }
  }
  s.deadline = deadline;
}

PdopSegmenter::TimePoint PdopSegmenter::scan_earliest() const {
  TimePoint earliest = TimePoint::max();
  for (const Stream& s : streams_) earliest = std::min(earliest, s.deadline);
  return earliest;
}

}  // namespace canbridge::bridge
