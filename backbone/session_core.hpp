// Every decision one backbone link's session makes (challenge-response and sealed envelopes when
// the session authenticates, hello exchange, refusals, binding, keepalive, dead and stale links,
// acknowledgement, resend requests, retransmission, what to write next), from the messages it is
// given and an injected `now`: no sockets, no timers, no coroutines.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <system_error>
#include <vector>

#include "backbone/envelope_codec.hpp"
#include "backbone/peer_stream.hpp"

namespace canbridge::backbone {

// What a SessionCore asks of the link it runs on; SessionLink forwards to its MessageLink, tests
// record it.
class SessionShell {
 public:
  // The core has something to write: call SessionCore::fill soon.
  virtual void wake_writer() = 0;
  // End the link; `reason` is what the link's client sees (errc::refused_by_peer: back off).
  virtual void close_link(std::error_code reason) = 0;
  // Stop (or resume) handing messages to SessionCore::on_message; the peer's writes back up.
  virtual void pause_reading(bool paused) = 0;
  // The peer's hello passed the version and role checks: which stream does it carry?
  virtual BindResult bind(const v1::Hello& peer) = 0;
  // This link carries `stream` from now on (close whatever link carried it before).
  virtual void carry(PeerStream& stream) = 0;
  // Bytes from the peer wait unread (this side was too busy to read them): asked only before the
  // link would be declared dead, since it may cost a syscall.
  virtual bool input_waiting() { return false; }

 protected:
  virtual ~SessionShell() = default;
};

// One link's session rules. Not thread-safe; every call on the link's thread.
class SessionCore {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // What the core knows of its link, fixed for the link's life.
  struct LinkFacts {
    std::string peer_name;    // "address:port" or the serial device, for logs
    bool crc_framed = false;  // a serial line: the peer may still be on its previous link
    // The identity the transport proved (TLS); empty when it proved none. A peer that proved
    // nothing (here or by the session's own authentication) is refused without the reason.
    std::string proven_peer;
  };

  // `preset`: the stream of a side with exactly one peer (the gateway), whose hello goes out
  // before the peer's arrives; null when SessionShell::bind picks it (the surface).
  SessionCore(const SessionIdentity& identity, const SessionOptions& options, PeerStream* preset,
              SessionCounters& counters, SessionLogMemory& log, SessionShell& shell,
              LinkFacts link);

  // The link is up: every silence is measured from now. Wakes the writer (a preset hello).
  void start(TimePoint now);
  // One message from the peer (a serialized Envelope without its length prefix). `now` may be
  // the time its input batch began (read once per batch): a keepalive that fell due meanwhile
  // is asked for here too, since a side busy with a long batch does not tick.
  void on_message(std::span<const std::uint8_t> bytes, TimePoint now);
  // Appends what to write now (delimited envelopes) to `out`: hello or refusal first, then
  // retransmissions, new reliable payloads, what the producer adds, and an ack if nothing else.
  void fill(std::string& out, TimePoint now);
  // Time passed: dead and stale links, keepalives, retransmission, repeated resend requests.
  // `reading_paused`: the link is not read (the silence is ours, not the peer's).
  // `bytes_arrived`: the link read bytes since the last tick, though perhaps no whole message (a
  // large message on a slow serial line takes seconds): the peer is alive. Before a link is
  // declared dead the shell is asked whether bytes wait unread (SessionShell::input_waiting).
  void on_tick(TimePoint now, bool reading_paused, bool bytes_arrived = false);
  // When on_tick is due. The core must be ticked about this often: the gap between ticks is
  // how it notices that it was not run (frozen, not scheduled) for longer than the peer waits.
  TimePoint next_deadline() const { return last_tick_ + tick_period(); }
  // The link ended. `carried`: it was the stream's link (the shell has let go of it already).
  void on_link_closed(bool carried, const std::string& reason);

  bool ready() const { return ready_; }
  bool closed() const { return closed_; }
  PeerStream* stream() const { return stream_; }
  // The peer's configured identity once the session's challenge-response proved it; empty before
  // and when the session does not authenticate (SessionOptions::authenticator).
  const std::string& authenticated_peer() const { return authenticated_peer_; }
  // The tick period SessionLink has always used: a quarter of the shortest timeout, 5..250 ms.
  Clock::duration tick_period() const;

 private:
  class Writer;

  // Input.
  bool accept_input(std::span<const std::uint8_t> bytes, TimePoint now);
  bool on_control(TimePoint now);
  void on_refusal();
  void before_ready(TimePoint now);
  bool on_acks(TimePoint now);
  bool on_payload(TimePoint now);
  // A keepalive's sent_through; true when a resend request is owed.
  bool on_keepalive(TimePoint now);
  void on_reliable_payload(std::span<const std::uint8_t> view, TimePoint now);
  void on_unreliable_payload(std::span<const std::uint8_t> view);
  void deliver_reliable(std::span<const std::uint8_t> payload);
  // Hello.
  void on_hello(const v1::Envelope& envelope, TimePoint now);
  void on_hello_again(const v1::Envelope& envelope, TimePoint now);
  bool check_hello(const v1::Hello& h);
  void adopt_peer_session(const v1::Hello& h);
  void become_ready();
  // A hello again on a ready link: the peer ended the link this one carried and began anew.
  void link_ended_unnoticed();
  void refuse(v1::Refusal::Reason reason, const std::string& detail, bool repeated = false);
  void protocol_error(const std::string& why);
  bool same_as_last_refusal(const std::string& text);
  // Authentication (SessionOptions::authenticator): handshake, then sealed envelopes.
  void on_handshake_message(std::span<const std::uint8_t> bytes, TimePoint now);
  void before_handshake(TimePoint now);
  void on_auth_step();
  void answer_challenge(const std::string& challenge);
  void queue_auth_step(std::span<const std::uint8_t> challenge,
                       std::span<const std::uint8_t> proof);
  void auth_established();
  void auth_failed(const AuthCounters& before, const std::string& why);
  void auth_failed(std::uint64_t& reason, const std::string& why);
  void on_unopened(std::span<const std::uint8_t> bytes, const AuthCounters& before);
  void peer_restarted(const char* what);
  void seal_into(const std::string& plain, std::string& out);
  // Output.
  void fill_envelopes(std::string& out, TimePoint now);
  bool fill_control(std::string& out, TimePoint now);
  void write_hello(std::string& out, TimePoint now);
  void fill_stream(std::string& out, TimePoint now);
  // Consumes the owed ack and resend request; valid until the next call.
  EnvelopeHeader next_header(std::uint64_t seq, std::uint64_t unreliable_seq);
  // Time.
  const char* stale_reason(TimePoint now) const;
  void close_stale(const char* why, TimePoint now);
  void tick_ready(TimePoint now, bool deaf);
  // Ready, and nothing written for a keepalive interval: a keepalive is owed from now; true when
  // it was not owed before (the writer must be woken).
  bool keepalive_due(TimePoint now);
  void drop_too_old(TimePoint now);
  Clock::duration peer_patience() const;
  Clock::duration resend_interval() const;
  void close(std::error_code reason);

  SessionIdentity identity_;
  SessionOptions options_;
  PeerStream* stream_;
  bool initiator_;  // sends its hello first (has a preset stream); the other side answers
  SessionCounters& counters_;
  SessionLogMemory& log_;
  SessionShell& shell_;
  LinkFacts link_;
  TimePoint last_rx_{};
  TimePoint last_tx_{};
  // Last time this side ran at all for the link (tick, input, writer): a long gap means it was
  // frozen or not scheduled, and the tick could not close the link in time.
  TimePoint last_run_{};
  TimePoint last_tick_{};
  std::string refusal_;  // serialized Refusal envelope waiting to go out
  v1::Envelope inbound_;
  v1::Envelope scratch_;
  std::vector<std::uint64_t> missing_;  // holes listed in the resend request being written
  bool hello_sent_ = false;
  bool peer_hello_ok_ = false;
  bool ready_ = false;
  bool closing_after_flush_ = false;
  bool ack_owed_ = false;
  bool resend_owed_ = false;
  bool keepalive_owed_ = false;
  bool hello_please_owed_ = false;
  TimePoint last_hello_request_{};
  // Authentication: this link's authenticator (null: the session does not authenticate), the
  // handshake step waiting to be written (unsealed), and the last one written, sent again when
  // the peer did not get it (the gateway's challenge; the surface's answer to a repeated one).
  std::unique_ptr<PeerAuthenticator> auth_;
  std::string auth_step_;
  std::string last_auth_step_;
  std::string answered_challenge_;  // surface: the challenge last_auth_step_ answers
  std::string sealing_;             // what fill wrote, before it is sealed
  std::string authenticated_peer_;
  bool closing_ = false;  // close_link was asked for: nothing more happens on this link
  bool closed_ = false;   // the link ended
};

}  // namespace canbridge::backbone
