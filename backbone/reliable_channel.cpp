#include "backbone/reliable_channel.hpp"

#include <algorithm>
#include <stdexcept>
#include <utility>

namespace canbridge::backbone {

namespace {
// First ring allocation; small so that a generous max_messages costs nothing until it is used.
constexpr std::size_t kInitialRingSize = 16;
}  // namespace

ReliableSender::ReliableSender(Options options) : options_(options) {
  if (options_.max_messages == 0 || options_.max_bytes == 0) {
    throw std::invalid_argument("ReliableSender: max_messages and max_bytes must be > 0");
  }
}

ReliableSender::Entry& ReliableSender::entry(std::uint64_t seq) {
  return ring_[(head_ + static_cast<std::size_t>(seq - send_base_)) % ring_.size()];
}

const ReliableSender::Entry& ReliableSender::entry(std::uint64_t seq) const {
  return ring_[(head_ + static_cast<std::size_t>(seq - send_base_)) % ring_.size()];
}

void ReliableSender::grow_ring() {
  const std::size_t new_size =
      std::min(options_.max_messages, std::max(kInitialRingSize, ring_.size() * 2));
  std::vector<Entry> grown(new_size);
  const std::size_t count = unacked_count();
  for (std::size_t i = 0; i < count; ++i) {
    grown[i] = std::move(ring_[(head_ + i) % ring_.size()]);
  }
  ring_ = std::move(grown);
  head_ = 0;
}

bool ReliableSender::can_accept(std::size_t bytes) const {
  return unacked_count() < options_.max_messages && bytes <= options_.max_bytes &&
         unacked_bytes_ <= options_.max_bytes - bytes;
}

std::optional<std::uint64_t> ReliableSender::push(std::string payload) {
  if (!can_accept(payload.size())) {
    ++counters_.overflow;
    return std::nullopt;
  }
  if (unacked_count() == ring_.size()) grow_ring();
  const std::uint64_t seq = next_seq_++;
  unacked_bytes_ += payload.size();
  Entry& stored = entry(seq);
  stored.payload = std::move(payload);
  stored.last_sent = TimePoint{};
  ++counters_.pushed;
  return seq;
}

std::optional<ReliableSender::Outgoing> ReliableSender::next_to_send(TimePoint now) {
  if (!has_unsent()) return std::nullopt;
  const std::uint64_t seq = cursor_++;
  Entry& sending = entry(seq);
  sending.last_sent = now;
  const bool retransmission = seq <= highest_sent_;
  highest_sent_ = std::max(highest_sent_, seq);
  ++counters_.sent;
  if (retransmission) ++counters_.retransmitted;
  return Outgoing{seq, sending.payload, retransmission};
}

void ReliableSender::on_ack(std::uint64_t cumulative, TimePoint now) {
  if (cumulative > highest_sent_) {
    ++counters_.bogus_acks;
    return;
  }
  if (cumulative < send_base_) return;  // stale, duplicated or reordered
  const std::size_t released = static_cast<std::size_t>(cumulative - send_base_ + 1);
  for (std::size_t i = 0; i < released; ++i) {
    Entry& done = ring_[(head_ + i) % ring_.size()];
    unacked_bytes_ -= done.payload.size();
    // Give the memory back now, so what is held tracks unacked_bytes().
    std::string().swap(done.payload);
  }
  head_ = (head_ + released) % ring_.size();
  send_base_ = cumulative + 1;
  cursor_ = std::max(cursor_, send_base_);
  last_ack_progress_ = now;
  counters_.acked += released;
}

void ReliableSender::rewind() {
  cursor_ = send_base_;
}

bool ReliableSender::on_resend_request(std::uint64_t ack, TimePoint now, Duration rto) {
  on_ack(ack, now);
  // A bogus ack was counted and ignored; a stale one reports a gap that has since been filled.
  if (ack > highest_sent_ || ack + 1 < send_base_) return false;
  if (last_resend_ack_ == ack && now - last_resend_rewind_ < rto) return false;
  last_resend_ack_ = ack;
  last_resend_rewind_ = now;
  rewind();
  return true;
}

bool ReliableSender::retransmit_due(TimePoint now, Duration rto) const {
  if (!link_up_ || cursor_ == send_base_) return false;  // oldest not sent on this link
  const TimePoint timer_start = std::max(entry(send_base_).last_sent, last_ack_progress_);
  return now - timer_start > rto;
}

void ReliableSender::on_link_up() {
  link_up_ = true;
  cursor_ = send_base_;
}

void ReliableSender::on_link_down() {
  link_up_ = false;
  cursor_ = send_base_;
}

ReliableReceiver::Verdict ReliableReceiver::accept(std::uint64_t seq) {
  if (seq == expected_) {
    ++expected_;
    ++counters_.delivered;
    return Verdict::deliver;
  }
  if (seq < expected_) {
    ++counters_.duplicates;
    return Verdict::duplicate;
  }
  ++counters_.gaps;
  return Verdict::gap;
}

void ReliableReceiver::reset(std::uint64_t next_expected) {
  expected_ = std::max<std::uint64_t>(next_expected, 1);
  last_request_expected_.reset();
}

bool ReliableReceiver::should_request_resend(TimePoint now, Duration rto) {
  if (last_request_expected_ == expected_ && now - last_request_ < rto) return false;
  last_request_expected_ = expected_;
  last_request_ = now;
  return true;
}

}  // namespace canbridge::backbone
