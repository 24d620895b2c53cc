// Sequencing for a session's reliable stream: the sender's bounded resend buffer and the
// receiver's in-order delivery with a bounded reorder buffer, so messages arrive exactly once and
// in order across losses, link cuts and reconnects. Losses are repaired by selective repeat (the
// receiver names the first missing seq, the sender resends only that one); go-back-N (rewind) is
// the fallback for link-up and for timeouts where the receiver cannot be assumed to buffer.
// Pure: no I/O, no timers; time is passed in by the caller.
#pragma once

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace canbridge::backbone {

// Sequence numbers start at 1 and stay monotonic for the process lifetime (0 means "unsequenced"
// on the wire). Not thread-safe.
//
// Typical use by a session:
//   link established:  on_link_up(); after the peer's hello: on_ack(peer_ack, now); rewind();
//   link lost:         on_link_down();
//   writer has room:   while (auto m = next_to_send(now)) write(m->seq, m->payload);
//   envelope received: on_ack(env.ack, now), or on_resend_request(env.ack, now, interval) if
//                      resend (interval: shorter than the rto, e.g. rto / 4), then on_nack(seq,
//                      now, interval) for each further missing seq the request lists, if any;
//   periodically:      if (retransmit_due(now, rto)) on_retransmit_timeout();
class ReliableSender {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  using Duration = std::chrono::steady_clock::duration;

  struct Options {
    std::size_t max_messages;  // unacknowledged messages held at most; > 0
    std::size_t max_bytes;     // total unacknowledged payload bytes held at most; > 0
  };

  struct Counters {
    std::uint64_t pushed = 0;         // messages accepted by push()
    std::uint64_t sent = 0;           // every hand-out by next_to_send(), retransmissions included
    std::uint64_t retransmitted = 0;  // hand-outs of a seq that had been handed out before
    std::uint64_t acked = 0;          // messages released by acknowledgements
    std::uint64_t overflow = 0;       // push() refused because a bound would be exceeded
    std::uint64_t bogus_acks = 0;     // acks above the highest seq ever sent (ignored)
    std::uint64_t selective_retransmits = 0;  // single-message resends (request or timeout)
    std::uint64_t timeouts = 0;               // on_retransmit_timeout() calls
    std::uint64_t timeout_rewinds = 0;        // of those, the ones that fell back to go-back-N
  };

  // What on_retransmit_timeout() did.
  enum class TimeoutAction {
    resend_oldest,  // only the oldest unacked is scheduled again
    rewind,         // go-back-N: every unacked message goes again
  };

  struct Outgoing {
    std::uint64_t seq;
    std::string_view payload;  // valid until the next non-const call on the sender
    bool retransmission;       // this seq was handed out before (on this or an earlier link)
  };

  // Throws std::invalid_argument when a bound is zero.
  explicit ReliableSender(Options options);

  // Whether push() of a payload of `bytes` would be accepted now; lets a producer hold back
  // (backpressure) instead of provoking an overflow.
  bool can_accept(std::size_t bytes) const;

  // Assigns the next seq and keeps the payload until it is acknowledged. nullopt (and counts
  // `overflow`) when max_messages or max_bytes would be exceeded; the caller must report that or
  // retry later. A payload larger than max_bytes is never accepted. `born`: when the oldest
  // content of the payload came into being (for drop_older_than(); the default never expires).
  std::optional<std::uint64_t> push(std::string payload, TimePoint born = TimePoint::max());

  // Single retransmissions scheduled by on_resend_request(), on_nack() or on_retransmit_timeout()
  // first, lowest seq first;
  // otherwise the next message not yet transmitted on the current link: after a rewind the oldest
  // unacked first, then onwards in seq order. Records `now` as its send time. nullopt while the
  // link is down or when nothing is scheduled and everything held has been handed out.
  std::optional<Outgoing> next_to_send(TimePoint now);

  // Releases every message <= `cumulative`. Stale acks (<= what is already acked) are ignored,
  // so acks may arrive duplicated or reordered. An ack above the highest seq ever sent cannot come
  // from a sane peer: it is counted in `bogus_acks` and ignored.
  void on_ack(std::uint64_t cumulative, TimePoint now);

  // Go-back-N: the next next_to_send() starts again at the oldest unacknowledged message (and a
  // scheduled single retransmission is dropped, as the rewind covers it).
  void rewind();

  // The peer is missing ack + 1 (it holds, or dropped, something after it): applies the ack, then
  // schedules a retransmission of ack + 1 alone, because a selective-repeat receiver buffers what
  // followed; resending the whole window would mostly deliver duplicates. Nothing is scheduled
  // when a request for the same ack was honoured less than `interval` ago (every message that
  // arrives after the gap may carry the same request), when ack + 1 has not been handed out on
  // this link yet (it goes out anyway), or when the ack is stale or bogus. Returns whether it
  // scheduled a retransmission. `interval` should be below the rto (e.g. rto / 4) so that a lost
  // retransmission is repaired before the timeout.
  bool on_resend_request(std::uint64_t ack, TimePoint now, Duration interval);

  // Optional extension for a wire format that lists further holes (ReliableReceiver::missing()):
  // schedules a retransmission of `seq` alone, if it is unacked, was handed out on this link, is
  // not already scheduled and was not (re)sent less than `interval` ago (that copy may still be
  // on its way; a later request names it again). Lets one request repair every hole in the window
  // instead of one hole per round trip, which is what bounds throughput on a very noisy line.
  // Apply the request's ack (on_resend_request) first. Returns whether it scheduled it.
  bool on_nack(std::uint64_t seq, TimePoint now, Duration interval);

  // The oldest unacked message has been handed out on the current link, no retransmission of it
  // is scheduled, and neither its send nor any acknowledgement progress happened within `rto` (as
  // TCP restarts its timer on new acks, so a long queue draining slowly over the link does not
  // look like a loss). The caller then calls on_retransmit_timeout().
  bool retransmit_due(TimePoint now, Duration rto) const;

  // Recovers from a timeout. Resends only the oldest unacked when the peer has reported that very
  // seq missing (so it has seen later ones and buffers them) and this is the first timeout since
  // the last ack progress. Otherwise rewinds: with no gap reported, the timeout most likely means
  // the tail of the window was lost (the peer saw nothing after it, so it has nothing buffered and
  // everything unacked must go again; resending one message per rto would take the whole window
  // times the rto); and a second timeout without progress means the peer may not hold what we
  // assume (its reorder buffer is bounded), so go-back-N restores progress at a bounded cost.
  TimeoutAction on_retransmit_timeout();

  // A new link: nothing held has been transmitted on it yet. next_to_send() hands out only while
  // the link is up; a new sender starts with the link down.
  void on_link_up();
  // Whatever was in flight is gone: after on_link_up() every unacked message goes again.
  void on_link_down();

  // Lets the application edit every unacknowledged payload in place (e.g. withdraw what it has
  // since told its user failed). Sequence numbers stay; a payload may become shorter or empty.
  template <typename Edit>
  void edit_unacked(Edit&& edit) {
    for (std::uint64_t seq = send_base_; seq < next_seq_; ++seq) {
      std::string& payload = entry(seq).payload;
      unacked_bytes_ -= payload.size();
      edit(payload);
      unacked_bytes_ += payload.size();
    }
  }

  // Turns every unacknowledged payload born before `cutoff` into a tombstone: the payload is
  // emptied, its seq stays (the peer's receiver may be waiting for it, so the stream stays
  // contiguous) and an empty reliable payload is never delivered. `dropped(const std::string&,
  // bool sent)` sees each payload before it is emptied; `sent`: it was handed out on some link
  // before, so the peer may have it already (only its ack is missing), and the tombstone then
  // stands for nothing lost. Returns how many were tombstoned.
  template <typename Dropped>
  std::size_t drop_older_than(TimePoint cutoff, Dropped&& dropped) {
    if (oldest_born_ >= cutoff) return 0;  // the common case: nothing that old is held
    std::size_t count = 0;
    TimePoint oldest = TimePoint::max();
    for (std::uint64_t seq = send_base_; seq < next_seq_; ++seq) {
      Entry& held = entry(seq);
      if (held.payload.empty()) continue;
      if (held.born >= cutoff) {
        oldest = std::min(oldest, held.born);
        continue;
      }
      dropped(static_cast<const std::string&>(held.payload), seq <= highest_sent_);
      tombstone(held);
      ++count;
    }
    oldest_born_ = oldest;
    return count;
  }
  // Tombstones every unacknowledged payload (the peer they were meant for is gone).
  template <typename Dropped>
  std::size_t drop_all(Dropped&& dropped) {
    std::size_t count = 0;
    for (std::uint64_t seq = send_base_; seq < next_seq_; ++seq) {
      Entry& held = entry(seq);
      if (held.payload.empty()) continue;
      dropped(static_cast<const std::string&>(held.payload));
      tombstone(held);
      ++count;
    }
    oldest_born_ = TimePoint::max();
    return count;
  }

  std::uint64_t send_base() const { return send_base_; }  // oldest unacked, or next_seq() if none
  // The highest seq handed out so far, on any link (0: none yet).
  std::uint64_t highest_sent() const { return highest_sent_; }
  std::uint64_t next_seq() const { return next_seq_; }  // seq the next push() gets
  std::size_t unacked_count() const { return static_cast<std::size_t>(next_seq_ - send_base_); }
  std::size_t unacked_bytes() const { return unacked_bytes_; }
  // Whether next_to_send() would hand out a message now.
  bool has_unsent() const { return link_up_ && (!scheduled_.empty() || cursor_ < next_seq_); }
  bool link_up() const { return link_up_; }
  const Counters& counters() const { return counters_; }
  // Smoothed time from a payload's (last) send to the acknowledgement that released it, ack
  // delay included (1/8 weight per sample, as TCP's SRTT); unset until measured on this link.
  std::optional<Duration> round_trip() const { return round_trip_; }

 private:
  struct Entry {
    std::string payload;
    TimePoint last_sent{};
    TimePoint born{};
  };
  void tombstone(Entry& held) {
    unacked_bytes_ -= held.payload.size();
    std::string().swap(held.payload);
  }

  Entry& entry(std::uint64_t seq);
  const Entry& entry(std::uint64_t seq) const;
  void grow_ring();

  Options options_;
  // Ring of unacked messages; entry(send_base_) sits at ring_[head_]. Grows on demand up to
  // max_messages and is reused afterwards, so steady state allocates only the payloads.
  std::vector<Entry> ring_;
  std::size_t head_ = 0;
  std::uint64_t send_base_ = 1;
  std::uint64_t next_seq_ = 1;
  std::uint64_t cursor_ = 1;  // next seq next_to_send() hands out
  std::uint64_t highest_sent_ = 0;
  std::size_t unacked_bytes_ = 0;
  bool link_up_ = false;
  TimePoint last_ack_progress_{};
  // No unacked payload was born before this (a lower bound), so drop_older_than() is cheap.
  TimePoint oldest_born_ = TimePoint::max();
  // Single retransmissions to hand out before anything else, lowest first. Only unacked seqs that
  // were handed out on this link (on_ack, rewind and link changes prune it), so it is bounded by
  // max_messages.
  std::set<std::uint64_t> scheduled_;
  std::optional<std::uint64_t> last_resend_ack_;  // last request honoured, for the throttle
  TimePoint last_resend_{};
  std::optional<std::uint64_t> reported_gap_ack_;  // ack of the latest valid resend request
  std::uint64_t timeouts_without_progress_ = 0;
  std::optional<Duration> round_trip_;
  Counters counters_;
};

// Accepts a peer's reliable stream and delivers it in order. Messages arriving after a gap are
// kept in a bounded reorder buffer and handed out once the gap is filled.
//
// Typical use by a session, for every received sequenced payload:
//   switch (accept(seq, payload)) {
//     case deliver:  hand `payload` to the application, then drain(...) the buffered ones;
//     case duplicate, buffered, gap: nothing to deliver;
//   }
//   if (should_request_resend(now, interval)) send a resend request (ack = cumulative_ack());
//   else acknowledge (ack = cumulative_ack()) on deliver/duplicate.
// and periodically (so a lost retransmission is asked for again even when nothing else arrives):
//   if (should_request_resend(now, interval)) send a resend request.
class ReliableReceiver {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  using Duration = std::chrono::steady_clock::duration;

  static constexpr std::size_t kDefaultMaxBufferedMessages = 64;
  static constexpr std::size_t kDefaultMaxBufferedBytes = 64 * 1024;

  enum class Verdict {
    deliver,    // the expected seq: hand it to the application, then drain the buffered ones
    duplicate,  // already delivered or already buffered: drop it, but re-acknowledge
    buffered,   // arrived after a gap and was copied into the reorder buffer
    gap,        // arrived after a gap and was dropped (outside the reorder window or bounds)
  };

  struct Counters {
    std::uint64_t delivered = 0;            // accept() deliveries plus drained buffered ones
    std::uint64_t duplicates = 0;           // both kinds of duplicate verdicts
    std::uint64_t buffered_duplicates = 0;  // of those, copies of a message still buffered
    std::uint64_t buffered = 0;             // messages put into the reorder buffer
    std::uint64_t gaps = 0;                 // messages dropped because they arrived after a gap
    std::uint64_t evicted = 0;  // buffered messages given up to make room for a lower seq
  };

  // The reorder buffer holds at most `max_buffered_messages` messages, all within that many seqs
  // after the expected one, and at most `max_buffered_bytes` payload bytes. Zero disables it
  // (pure go-back-N reception).
  explicit ReliableReceiver(std::size_t max_buffered_messages = kDefaultMaxBufferedMessages,
                            std::size_t max_buffered_bytes = kDefaultMaxBufferedBytes);

  // Classifies `seq`; for `buffered` the payload has been copied. After `deliver` the caller must
  // drain() (or call next_buffered() until nullopt) before the next accept() to keep the order;
  // should it not, a later arrival of the next seq is still delivered exactly once.
  Verdict accept(std::uint64_t seq, std::string_view payload);

  // The buffered payload of the expected seq, which it then counts as delivered; nullopt when the
  // expected seq is not buffered (still missing, or nothing buffered).
  std::optional<std::string> next_buffered();

  // Hands every now-in-order buffered payload to `deliver(std::string&&)`, in seq order.
  template <class F>
  void drain(F&& deliver) {
    while (auto payload = next_buffered()) deliver(std::move(*payload));
  }

  // Every seq up to this one has been delivered; carried as Envelope.ack.
  std::uint64_t cumulative_ack() const { return expected_ - 1; }
  std::uint64_t expected() const { return expected_; }
  // The seq a resend request names (cumulative_ack() + 1); only missing while has_gap().
  std::uint64_t first_missing() const { return expected_; }
  // The highest seq seen since the last reset, delivered or not (cumulative_ack() if none).
  std::uint64_t highest_seen() const { return highest_seen_; }
  // Something after first_missing() has arrived (buffered or dropped), or the peer said it sent
  // it (note_sent_through), so first_missing() is lost.
  bool has_gap() const { return highest_seen_ >= expected_; }
  // The peer says it has sent every seq up to `seq` (its keepalive): what of that never arrived is
  // missing, the tail included, which no later message would show as a gap. Bounded by the
  // reorder window, so a bogus value cannot make the receiver ask for seqs without end.
  void note_sent_through(std::uint64_t seq) {
    highest_seen_ = std::max(highest_seen_, std::min(seq, expected_ + max_buffered_messages_));
  }

  // Up to `max_count` seqs, ascending from first_missing(), that are neither delivered nor
  // buffered although a later seq has arrived, within the reorder window (what lies beyond it
  // could not be buffered now). Empty unless has_gap(). For a wire format that can list holes
  // in a resend request (see ReliableSender::on_nack).
  std::vector<std::uint64_t> missing(std::size_t max_count) const;

  std::size_t buffered_count() const { return buffer_.size(); }
  std::size_t buffered_bytes() const { return buffered_bytes_; }

  // The peer restarted (a new session): start expecting exactly `next_expected` (its hello's
  // send_base) and forget what was buffered. 0 is taken as 1, since sequence numbers start there.
  void reset(std::uint64_t next_expected);

  // Whether to send a resend request for first_missing() now: only while has_gap(), and at most
  // once per missing seq per `interval`, because every message arriving after the gap reports the
  // same gap. A new first_missing() (the previous one arrived, the next hole shows) is reported at
  // once. Safe to call after every accept() and periodically.
  bool should_request_resend(TimePoint now, Duration interval);

  const Counters& counters() const { return counters_; }

 private:
  std::size_t max_buffered_messages_;
  std::size_t max_buffered_bytes_;
  std::uint64_t expected_ = 1;
  std::uint64_t highest_seen_ = 0;
  // Ordered, so the lowest (next to deliver) and the highest (first to evict) are at the ends.
  std::map<std::uint64_t, std::string> buffer_;
  std::size_t buffered_bytes_ = 0;
  std::optional<std::uint64_t> last_request_expected_;
  TimePoint last_request_{};
  Counters counters_;
};

}  // namespace canbridge::backbone
