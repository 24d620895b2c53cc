// What a backbone session keeps toward one peer across its links (PeerStream: the reliable
// streams both ways), and what every link of a side shares: options, counters, identity, binding.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "backbone/peer_authenticator.hpp"
#include "backbone/reliable_channel.hpp"
#include "session.pb.h"

namespace canbridge::backbone {

inline constexpr std::uint32_t kProtocolMajor = 2;
// 1: a second application payload kind; 2: PDO Packets (three more kinds); 3: Hello.application
// (a gateway's claims, checked by the surface); 4: Envelope.auth (the serial challenge-response
// before the hellos, then sealed envelopes); 5: remote access (RemoteRequest and its answers);
// 6: FrameBatch.head_runs (bridge::kHeadRunsMinor); 7: Keepalive.sent_through (a lost tail is
// asked for at the next keepalive)
inline constexpr std::uint32_t kProtocolMinor = 7;

struct SessionOptions {
  // Nothing sent for this long: send a keepalive (it carries the current ack).
  std::chrono::milliseconds keepalive_interval{500};
  // Nothing valid received for this long (hello included): the link is dead and is closed; the
  // transport's client reconnects with backoff.
  std::chrono::milliseconds dead_after{2000};
  // Oldest unacknowledged reliable message sent this long ago: go back and resend from it.
  std::chrono::milliseconds retransmit_timeout{1000};
  // Bounds of the resend buffer (reliable payloads sent and not yet acknowledged). When full,
  // new reliable payloads wait upstream (PayloadSink::reliable_room() says no).
  std::size_t resend_buffer_messages = 4096;
  std::size_t resend_buffer_bytes = 4u << 20;
  // Upper bound of one write: what is urgent does not wait behind a long write on a slow line.
  std::size_t max_write_bytes = 16 * 1024;
  // A reliable payload older than this (from its birth upstream, see PayloadSink) is never sent
  // again: it becomes a tombstone (PeerStream::Handlers::on_reliable_dropped). A command that
  // arrives seconds late does harm (an NMT stop for a node its master has since restarted).
  // Zero: no limit.
  std::chrono::milliseconds reliable_max_age{0};
  // The session's clock; empty: std::chrono::steady_clock::now. Tests inject their own.
  std::function<std::chrono::steady_clock::time_point()> clock;
  // The session's own authentication (serial lines; TCP has TLS): called once per link with the
  // link's name (a serial device, "address:port"); a fresh authenticator (new nonces, keys and
  // counters) runs the challenge-response before the hellos and seals every envelope after it.
  // Null, or an empty function: this link is not authenticated by the session.
  std::function<std::unique_ptr<PeerAuthenticator>(const std::string& link_name)> authenticator;
};

// Counters of one side, summed over all its peers and links.
struct SessionCounters {
  std::uint64_t links = 0;              // links that completed the hello exchange
  std::uint64_t dead_links = 0;         // closed by dead-link detection
  std::uint64_t refusals_sent = 0;      // hellos this side refused (version, role, duplicate)
  std::uint64_t refusals_received = 0;  // the peer refused this side
  std::uint64_t protocol_errors = 0;    // data before hello, second hello, ...
  std::uint64_t before_hello = 0;       // serial: messages ignored while waiting for a hello
  std::uint64_t malformed = 0;          // messages that are not a valid Envelope
  std::uint64_t keepalives_sent = 0;
  std::uint64_t resend_requests = 0;  // gaps seen in a peer's reliable stream
  std::uint64_t peer_restarts = 0;    // a known peer came back with a new session id
  std::uint64_t reliable_sent = 0;    // payloads, first transmissions
  std::uint64_t reliable_resent = 0;  // payloads, retransmissions
  std::uint64_t reliable_delivered = 0;
  std::uint64_t reliable_duplicates = 0;  // dropped: already delivered
  std::uint64_t unreliable_sent = 0;
  std::uint64_t unreliable_delivered = 0;
  // Input arrived after the link had been silent past dead_after, or after this side had not run
  // for longer than the peer's patience (frozen, not scheduled): the peer may have declared the
  // link dead and withdrawn what it sent, so that input was not delivered and the link closed.
  std::uint64_t stale_links_closed = 0;
  // Older than reliable_max_age before it was ever sent: dropped, the peer never had it.
  std::uint64_t reliable_dropped_too_old = 0;
  // Older than reliable_max_age after it was sent, unacknowledged: tombstoned, but the peer may
  // have it (only its ack was late). Not a drop count: the peer's tombstones_received counts the
  // ones that did not arrive.
  std::uint64_t reliable_expired_unacked = 0;
  std::uint64_t reliable_dropped_peer_restart = 0;  // tombstoned: meant for the peer's old process
  std::uint64_t tombstones_received = 0;            // empty reliable payloads, not delivered
  std::uint64_t unreliable_lost = 0;  // gaps in a peer's unreliable sequence: lost on the line
  // Session authentication (SessionOptions::authenticator): handshakes completed, handshakes
  // refused by reason, and sealed envelopes that did not open (dropped, never delivered).
  std::uint64_t auth_established = 0;
  std::uint64_t auth_failed_bad_proof = 0;        // wrong key, forged or reflected proof
  std::uint64_t auth_failed_unknown_key = 0;      // surface: the gateway's key id is none of ours
  std::uint64_t auth_failed_malformed = 0;        // malformed step, another tag size, wrong order
  std::uint64_t auth_failed_unauthenticated = 0;  // the peer skipped it (or we do not do it)
  std::uint64_t auth_restarts = 0;  // the peer restarted its end of an authenticated line
  std::uint64_t rejected_truncated = 0;
  std::uint64_t rejected_bad_tag = 0;  // tampered, forged or unsealed
  std::uint64_t rejected_replay = 0;   // authentic but not newer: replayed or reordered
};

// What one side has said in its log already, shared by its links like SessionCounters: a repeat
// (the same refusal on every reconnect, a flood of bad envelopes) is only counted.
struct SessionLogMemory {
  bool warned_malformed = false;
  bool warned_rejected = false;  // a sealed envelope that did not open
  bool warned_protocol_error = false;
  std::string last_refusal;
};

// Why a reliable payload was dropped before its peer acknowledged it.
enum class ReliableDrop {
  too_old,          // older than SessionOptions::reliable_max_age, never sent: the peer lacks it
  too_old_unacked,  // ... after it was sent, unacknowledged: the peer may have it
  peer_restart,     // the peer is a new process: it never asked for what the old one was sent
};

class SessionLink;
class SessionCore;

// What a PeerStream's producer writes into: it asks for room, then hands over payloads.
class PayloadSink {
 public:
  virtual ~PayloadSink() = default;
  // Bytes the current write can still take.
  virtual std::size_t room() const = 0;
  // Whether the resend buffer can hold a reliable payload of `bytes` (else: keep it upstream).
  virtual bool reliable_room(std::size_t bytes) const = 0;
  // Born now: its age (SessionOptions::reliable_max_age) counts from this call.
  virtual void send_reliable(std::string payload) = 0;
  // Born at `born`: content that waited upstream (a queue while the link was down) is as old as
  // its oldest part.
  virtual void send_reliable_since(std::string payload,
                                   std::chrono::steady_clock::time_point born) {
    (void)born;
    send_reliable(std::move(payload));
  }
  virtual void send_unreliable(std::span<const std::uint8_t> payload) = 0;
  // The session's clock, for producers that age what they queue.
  virtual std::chrono::steady_clock::time_point now() const {
    return std::chrono::steady_clock::now();
  }
};

// Reliable state toward one peer; outlives the links that carry it.
class PeerStream {
 public:
  struct Handlers {
    // Fills the current write (called whenever the link can take more).
    std::function<void(PayloadSink&)> produce;
    // One received payload: reliable ones exactly once and in order.
    std::function<void(std::span<const std::uint8_t> payload, bool reliable)> on_payload;
    std::function<void(const v1::Hello& peer)> on_up;  // a link to the peer is ready
    std::function<void()> on_down;                     // that link ended
    // The peer's hello names a new process (not the first one seen): whatever the application
    // still queues for the old one must go. Called before the new link carries anything.
    std::function<void(const v1::Hello& peer)> on_peer_restart = nullptr;
    // A reliable payload given up before its peer acknowledged it (then emptied: a tombstone).
    std::function<void(const std::string& payload, ReliableDrop why)> on_reliable_dropped = nullptr;
  };

  PeerStream(const SessionOptions& options, Handlers handlers);

  // Asks the current link (if any) to call produce() soon. Cheap; call after queueing.
  void wake();
  bool up() const { return link_ != nullptr; }
  const v1::Hello& peer_hello() const { return peer_hello_; }
  const ReliableSender& sender() const { return sender_; }
  // ReliableSender::edit_unacked, for the application.
  template <typename Edit>
  void edit_unacked(Edit&& edit) {
    sender_.edit_unacked(std::forward<Edit>(edit));
  }
  const ReliableReceiver& receiver() const { return receiver_; }
  // Closes the current link, if any.
  void close_link();
  // While paused, payloads from the peer stay unread on its links (this one and later ones), so
  // the peer's resend window bounds what the application must hold: for an application whose
  // output is backed up. Keepalives still go out, and the silence is not held against the peer.
  void pause_input(bool paused);
  bool input_paused() const { return input_paused_; }

 private:
  friend class SessionLink;
  friend class SessionCore;
  class SessionCore;
  ReliableSender sender_;
  ReliableReceiver receiver_;
  std::uint64_t peer_session_id_ = 0;  // 0: never heard of the peer
  // The latest refusal the peer sent since this stream was last up: a refused peer retries, and
  // the same refusal again is logged at debug level only.
  std::string last_refusal_;
  std::uint64_t unreliable_sent_ = 0;  // Envelope.unreliable_seq of the last one sent
  std::uint64_t unreliable_seen_ = 0;  // ... the highest received from the peer's session
  v1::Hello peer_hello_;
  Handlers handlers_;
  std::shared_ptr<SessionLink> link_;  // set while a link to the peer is ready
  bool input_paused_ = false;
};

// Decides, on the peer's hello, which stream a link carries (the surface has one per gateway).
struct BindResult {
  PeerStream* stream = nullptr;  // null: refused
  v1::Refusal::Reason reason = v1::Refusal::PROTOCOL_ERROR;
  std::string detail;  // why, for both sides' logs
  // The binder refused this peer for this very reason before: log it at debug level only.
  bool repeated = false;
};

// Who this side is: what its hello says.
struct SessionIdentity {
  v1::Hello::Role role = v1::Hello::ROLE_UNSPECIFIED;
  v1::Hello::Role expected_peer = v1::Hello::ROLE_UNSPECIFIED;
  std::string name;
  std::vector<std::uint32_t> module_ids;
  std::uint64_t session_id = 0;  // random per process start (random_session_id())
  std::string application;       // Hello.application, opaque to the session
};

// "name (role, protocol a.b)", for logs.
std::string describe_peer(const v1::Hello& hello);

// "gateway", "surface", for logs.
const char* role_name(v1::Hello::Role role);

}  // namespace canbridge::backbone
