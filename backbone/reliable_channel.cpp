#include "backbone/reliable_channel.hpp"

#include <algorithm>
#include <iterator>
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

std::optional<std::uint64_t> ReliableSender::push(std::string payload, TimePoint born) {
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
  stored.born = born;
  oldest_born_ = std::min(oldest_born_, born);
  ++counters_.pushed;
  return seq;
}

std::optional<ReliableSender::Outgoing> ReliableSender::next_to_send(TimePoint now) {
  if (!has_unsent()) return std::nullopt;
  std::uint64_t seq = 0;
  while (!scheduled_.empty() && seq == 0) {
    const std::uint64_t scheduled = *scheduled_.begin();
    scheduled_.erase(scheduled_.begin());
    // Scheduling and on_ack keep it within [send_base_, cursor_); checked anyway, since handing
    // out a released seq would read a ring slot that holds another message or none.
    if (scheduled >= send_base_ && scheduled < cursor_) seq = scheduled;
  }
  if (seq != 0) {
    ++counters_.selective_retransmits;
  } else if (cursor_ < next_seq_) {
    seq = cursor_++;
  } else {
    return std::nullopt;
  }
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
  // The newest payload released was sent last: its send time gives the freshest sample.
  const TimePoint sent = ring_[(head_ + released - 1) % ring_.size()].last_sent;
  if (sent != TimePoint{} && now >= sent) {
    const Duration sample = now - sent;
    round_trip_ = round_trip_ ? *round_trip_ + (sample - *round_trip_) / 8 : sample;
  }
  for (std::size_t i = 0; i < released; ++i) {
    Entry& done = ring_[(head_ + i) % ring_.size()];
    unacked_bytes_ -= done.payload.size();
    // Give the memory back now, so what is held tracks unacked_bytes().
    std::string().swap(done.payload);
  }
  head_ = (head_ + released) % ring_.size();
  send_base_ = cumulative + 1;
  cursor_ = std::max(cursor_, send_base_);
  // Delivered after all: no retransmission needed.
  scheduled_.erase(scheduled_.begin(), scheduled_.lower_bound(send_base_));
  last_ack_progress_ = now;
  timeouts_without_progress_ = 0;
  counters_.acked += released;
}

void ReliableSender::rewind() {
  cursor_ = send_base_;
  scheduled_.clear();
}

bool ReliableSender::on_resend_request(std::uint64_t ack, TimePoint now, Duration interval) {
  on_ack(ack, now);
  // A bogus ack was counted and ignored; a stale one reports a gap that has since been filled.
  if (ack > highest_sent_ || ack + 1 < send_base_) return false;
  reported_gap_ack_ = ack;
  const std::uint64_t missing = ack + 1;
  // Not handed out on this link yet (or nothing to resend): the cursor sends it in due course.
  if (missing >= cursor_) return false;
  if (scheduled_.contains(missing)) return false;
  if (last_resend_ack_ == ack && now - last_resend_ < interval) return false;
  last_resend_ack_ = ack;
  last_resend_ = now;
  scheduled_.insert(missing);
  return true;
}

bool ReliableSender::on_nack(std::uint64_t seq, TimePoint now, Duration interval) {
  if (seq < send_base_ || seq >= cursor_ || scheduled_.contains(seq)) return false;
  if (now - entry(seq).last_sent < interval) return false;
  scheduled_.insert(seq);
  return true;
}

bool ReliableSender::retransmit_due(TimePoint now, Duration rto) const {
  if (!link_up_ || cursor_ == send_base_) return false;  // oldest not sent on this link
  if (scheduled_.contains(send_base_)) return false;     // its resend is already on the way
  const TimePoint timer_start = std::max(entry(send_base_).last_sent, last_ack_progress_);
  return now - timer_start > rto;
}

ReliableSender::TimeoutAction ReliableSender::on_retransmit_timeout() {
  ++counters_.timeouts;
  const bool first_timeout = timeouts_without_progress_++ == 0;
  const bool peer_reported_it_missing =
      reported_gap_ack_.has_value() && *reported_gap_ack_ + 1 == send_base_;
  if (first_timeout && peer_reported_it_missing && cursor_ > send_base_) {
    scheduled_.insert(send_base_);
    return TimeoutAction::resend_oldest;
  }
  ++counters_.timeout_rewinds;
  rewind();
  return TimeoutAction::rewind;
}

void ReliableSender::on_link_up() {
  link_up_ = true;
  round_trip_.reset();  // a new link: a new path
  cursor_ = send_base_;
  scheduled_.clear();
}

void ReliableSender::on_link_down() {
  link_up_ = false;
  cursor_ = send_base_;
  scheduled_.clear();
}

ReliableReceiver::ReliableReceiver(std::size_t max_buffered_messages,
                                   std::size_t max_buffered_bytes)
    : max_buffered_messages_(max_buffered_messages), max_buffered_bytes_(max_buffered_bytes) {}

ReliableReceiver::Verdict ReliableReceiver::accept(std::uint64_t seq, std::string_view payload) {
  if (seq < expected_) {
    ++counters_.duplicates;
    return Verdict::duplicate;
  }
  highest_seen_ = std::max(highest_seen_, seq);
  if (seq == expected_) {
    // Only if the caller skipped draining: the buffered copy must not be delivered a second time.
    if (auto stale = buffer_.find(seq); stale != buffer_.end()) {
      buffered_bytes_ -= stale->second.size();
      buffer_.erase(stale);
    }
    ++expected_;
    ++counters_.delivered;
    return Verdict::deliver;
  }
  if (buffer_.contains(seq)) {
    ++counters_.duplicates;
    ++counters_.buffered_duplicates;
    return Verdict::duplicate;
  }
  // The window bound keeps the count bound, and keeps a runaway seq from pinning memory until a
  // long run of gaps is filled.
  if (seq - expected_ > max_buffered_messages_ || payload.size() > max_buffered_bytes_) {
    ++counters_.gaps;
    return Verdict::gap;
  }
  // Over the byte bound, give up the highest buffered seqs for a lower one: the lower the seq,
  // the sooner it can be delivered, and what is given up is asked for again later.
  while (buffered_bytes_ + payload.size() > max_buffered_bytes_ && !buffer_.empty() &&
         buffer_.rbegin()->first > seq) {
    auto highest = std::prev(buffer_.end());
    buffered_bytes_ -= highest->second.size();
    buffer_.erase(highest);
    ++counters_.evicted;
  }
  if (buffered_bytes_ + payload.size() > max_buffered_bytes_) {
    ++counters_.gaps;
    return Verdict::gap;
  }
  buffer_.emplace(seq, std::string(payload));
  buffered_bytes_ += payload.size();
  ++counters_.buffered;
  return Verdict::buffered;
}

std::optional<std::string> ReliableReceiver::next_buffered() {
  if (buffer_.empty() || buffer_.begin()->first != expected_) return std::nullopt;
  std::string payload = std::move(buffer_.begin()->second);
  buffer_.erase(buffer_.begin());
  buffered_bytes_ -= payload.size();
  ++expected_;
  ++counters_.delivered;
  return payload;
}

std::vector<std::uint64_t> ReliableReceiver::missing(std::size_t max_count) const {
  std::vector<std::uint64_t> holes;
  if (!has_gap()) return holes;
  const std::uint64_t last = std::min(highest_seen_, expected_ + max_buffered_messages_);
  auto held = buffer_.begin();  // walks along, as buffer_ is ordered
  for (std::uint64_t seq = expected_; seq <= last && holes.size() < max_count; ++seq) {
    while (held != buffer_.end() && held->first < seq) ++held;
    if (held == buffer_.end() || held->first != seq) holes.push_back(seq);
  }
  return holes;
}

void ReliableReceiver::reset(std::uint64_t next_expected) {
  expected_ = std::max<std::uint64_t>(next_expected, 1);
  highest_seen_ = expected_ - 1;
  buffer_.clear();
  buffered_bytes_ = 0;
  last_request_expected_.reset();
}

bool ReliableReceiver::should_request_resend(TimePoint now, Duration interval) {
  if (!has_gap()) return false;
  if (last_request_expected_ == expected_ && now - last_request_ < interval) return false;
  last_request_expected_ = expected_;
  last_request_ = now;
  return true;
}

}  // namespace canbridge::backbone
