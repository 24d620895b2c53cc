// Go-back-N sequencing for a session's reliable stream: the sender's bounded resend buffer and the
// receiver's in-order acceptance, so messages arrive exactly once and in order across losses, link
// cuts and reconnects. Pure: no I/O, no timers; time is passed in by the caller.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace canbridge::backbone {

// Sequence numbers start at 1 and stay monotonic for the process lifetime (0 means "unsequenced"
// on the wire). Not thread-safe.
//
// Typical use by a session:
//   link established:  on_link_up(); after the peer's hello: on_ack(peer_ack, now); rewind();
//   link lost:         on_link_down();
//   writer has room:   while (auto m = next_to_send(now)) write(m->seq, m->payload);
//   envelope received: on_ack(env.ack, now), or on_resend_request(env.ack, now, rto) if resend;
//   periodically:      if (retransmit_due(now, rto)) rewind();
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
  // retry later. A payload larger than max_bytes is never accepted.
  std::optional<std::uint64_t> push(std::string payload);

  // The next message not yet transmitted on the current link: after a rewind the oldest unacked
  // first, then onwards in seq order. Records `now` as its send time. nullopt while the link is
  // down or when everything held has been handed out on this link.
  std::optional<Outgoing> next_to_send(TimePoint now);

  // Releases every message <= `cumulative`. Stale acks (<= what is already acked) are ignored,
  // so acks may arrive duplicated or reordered. An ack above the highest seq ever sent cannot come
  // from a sane peer: it is counted in `bogus_acks` and ignored.
  void on_ack(std::uint64_t cumulative, TimePoint now);

  // The next next_to_send() starts again at the oldest unacknowledged message.
  void rewind();

  // The peer saw a gap after `ack`: applies the ack, then rewinds, unless a request for the same
  // ack already caused a rewind less than `rto` ago (a burst of identical requests, one per
  // message arriving after the gap, must not cause a retransmission storm). Requests whose ack is
  // stale or bogus do not rewind either. Returns whether it rewound.
  bool on_resend_request(std::uint64_t ack, TimePoint now, Duration rto);

  // The oldest unacked message has been handed out on the current link, and neither its send nor
  // any acknowledgement progress happened within `rto` (as TCP restarts its timer on new acks, so
  // a long queue draining slowly over the link does not look like a loss). The caller rewinds.
  bool retransmit_due(TimePoint now, Duration rto) const;

  // A new link: nothing held has been transmitted on it yet. next_to_send() hands out only while
  // the link is up; a new sender starts with the link down.
  void on_link_up();
  // Whatever was in flight is gone: after on_link_up() every unacked message goes again.
  void on_link_down();

  std::uint64_t send_base() const { return send_base_; }  // oldest unacked, or next_seq() if none
  std::uint64_t next_seq() const { return next_seq_; }    // seq the next push() gets
  std::size_t unacked_count() const { return static_cast<std::size_t>(next_seq_ - send_base_); }
  std::size_t unacked_bytes() const { return unacked_bytes_; }
  // Whether next_to_send() would hand out a message now.
  bool has_unsent() const { return link_up_ && cursor_ < next_seq_; }
  bool link_up() const { return link_up_; }
  const Counters& counters() const { return counters_; }

 private:
  struct Entry {
    std::string payload;
    TimePoint last_sent{};
  };

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
  std::optional<std::uint64_t> last_resend_ack_;
  TimePoint last_resend_rewind_{};
  Counters counters_;
};

// Accepts a peer's reliable stream in order; what it does not deliver the caller drops.
class ReliableReceiver {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  using Duration = std::chrono::steady_clock::duration;

  enum class Verdict {
    deliver,    // the expected seq: hand it to the application
    duplicate,  // already delivered (a retransmission): drop it, but re-acknowledge
    gap,        // something before it was lost: drop it and request a resend
  };

  struct Counters {
    std::uint64_t delivered = 0;
    std::uint64_t duplicates = 0;
    std::uint64_t gaps = 0;  // messages dropped because they arrived after a gap
  };

  Verdict accept(std::uint64_t seq);

  // Every seq up to this one has been delivered; carried as Envelope.ack.
  std::uint64_t cumulative_ack() const { return expected_ - 1; }
  std::uint64_t expected() const { return expected_; }

  // The peer restarted (a new session): start expecting exactly `next_expected` (its hello's
  // send_base). 0 is taken as 1, since sequence numbers start there.
  void reset(std::uint64_t next_expected);

  // Call after a gap verdict: whether to send a resend request now. At most one per expected seq
  // per `rto`, because every message arriving after the gap reports the same gap.
  bool should_request_resend(TimePoint now, Duration rto);

  const Counters& counters() const { return counters_; }

 private:
  std::uint64_t expected_ = 1;
  std::optional<std::uint64_t> last_request_expected_;
  TimePoint last_request_{};
  Counters counters_;
};

}  // namespace canbridge::backbone
