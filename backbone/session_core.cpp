#include "backbone/session_core.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>

#include "backbone/delimited_codec.hpp"
#include "backbone/envelope_codec.hpp"

namespace canbridge::backbone {

namespace {

using Clock = std::chrono::steady_clock;

// Holes listed in one resend request: enough to repair a burst in one round trip.
constexpr std::size_t kMaxMissingListed = 16;

std::span<const std::uint8_t> bytes_of(std::string_view s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

long long ms(Clock::duration d) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(d).count();
}

}  // namespace

const char* role_name(v1::Hello::Role role) {
  switch (role) {
    case v1::Hello::ROLE_GATEWAY:
      return "gateway";
    case v1::Hello::ROLE_SURFACE:
      return "surface";
    default:
      return "unspecified";
  }
}

std::string describe_peer(const v1::Hello& hello) {
  return "'" + hello.name() + "' (" + role_name(hello.role()) + ", protocol " +
         std::to_string(hello.protocol_major()) + "." + std::to_string(hello.protocol_minor()) +
         ")";
}

// ---------------------------------------------------------------------------------------------
// The producer's view of one write: what fits, and where payloads go.
class SessionCore::Writer final : public PayloadSink {
 public:
  Writer(SessionCore& core, std::string& out, Clock::time_point now)
      : core_(core), out_(out), start_(out.size()), now_(now) {}

  std::size_t room() const override {
    const std::size_t used = out_.size() - start_;
    const std::size_t max = core_.options_.max_write_bytes;
    return used >= max ? 0 : max - used;
  }
  bool reliable_room(std::size_t bytes) const override {
    return core_.stream_->sender_.can_accept(bytes);
  }
  void send_reliable(std::string payload) override {
    send_reliable_since(std::move(payload), now_);
  }
  void send_reliable_since(std::string payload, Clock::time_point born) override {
    const auto max_age = core_.options_.reliable_max_age;
    if (max_age.count() > 0 && now_ - born > max_age) {
      // Too old already: never sequenced, never sent.
      ++core_.counters_.reliable_dropped_too_old;
      auto& dropped = core_.stream_->handlers_.on_reliable_dropped;
      if (dropped) dropped(payload, ReliableDrop::too_old);
      return;
    }
    // Counted by the sender when refused.
    if (!core_.stream_->sender_.push(std::move(payload), std::min(born, now_))) return;
    drain_reliable();
  }
  Clock::time_point now() const override { return now_; }
  void send_unreliable(std::span<const std::uint8_t> payload) override {
    append_payload_envelope(out_, core_.next_header(0, ++core_.stream_->unreliable_sent_), payload);
    ++core_.counters_.unreliable_sent;
  }

  // Sends what the resend buffer holds and this link has not carried yet, as room allows.
  void drain_reliable() {
    ReliableSender& sender = core_.stream_->sender_;
    while (room() > 0) {
      auto next = sender.next_to_send(now_);
      if (!next) break;
      append_payload_envelope(out_, core_.next_header(next->seq, 0), bytes_of(next->payload));
      ++(next->retransmission ? core_.counters_.reliable_resent : core_.counters_.reliable_sent);
    }
  }

  bool wrote() const { return out_.size() != start_; }

 private:
  SessionCore& core_;
  std::string& out_;
  std::size_t start_;
  Clock::time_point now_;
};

// ---------------------------------------------------------------------------------------------
SessionCore::SessionCore(const SessionIdentity& identity, const SessionOptions& options,
                         PeerStream* preset, SessionCounters& counters, SessionLogMemory& log,
                         SessionShell& shell, LinkFacts link)
    : identity_(identity),
      options_(options),
      stream_(preset),
      initiator_(preset != nullptr),
      counters_(counters),
      log_(log),
      shell_(shell),
      link_(std::move(link)) {
  // One authenticator per link: new nonces, new keys, and counters that start with the link.
  if (options_.authenticator) auth_ = options_.authenticator(link_.peer_name);
}

void SessionCore::start(TimePoint now) {
  last_rx_ = last_tx_ = last_run_ = last_tick_ = now;
  if (auth_ && auth_->role() == AuthRole::gateway) {
    // The gateway opens the handshake; its hello follows once both ends are proven.
    const AuthCounters before = auth_->counters();
    const auto challenge = auth_->make_challenge();
    if (!challenge) return auth_failed(before, "no challenge (random source failed)");
    queue_auth_step(*challenge, {});
  }
  shell_.wake_writer();  // a preset stream's hello (or the challenge) goes out at once
}

void SessionCore::close(std::error_code reason) {
  closing_ = true;
  shell_.close_link(reason);
}

void SessionCore::on_link_closed(bool carried, const std::string& reason) {
  if (closed_) return;
  closed_ = true;
  closing_ = true;
  if (!carried) return;
  stream_->sender_.on_link_down();
  // What waits here behind a gap is still unacknowledged at the peer, which resends it on the
  // next link, and may have withdrawn part of it meanwhile (SDO requests its master was told
  // had failed): only the peer's resent version may be delivered.
  stream_->receiver_.reset(stream_->receiver_.expected());
  spdlog::info("backbone: link to {} over {} closed ({})", describe_peer(stream_->peer_hello_),
               link_.peer_name, reason);
  if (stream_->handlers_.on_down) stream_->handlers_.on_down();
}

// Resend requests and single retransmissions are throttled to this, well below the retransmit
// timeout, so a lost retransmission is asked for again long before the timeout falls back.
Clock::duration SessionCore::resend_interval() const {
  return std::max<Clock::duration>(options_.retransmit_timeout / 4, std::chrono::milliseconds{1});
}

Clock::duration SessionCore::tick_period() const {
  const auto shortest =
      std::min({options_.keepalive_interval, options_.dead_after, options_.retransmit_timeout});
  return std::clamp(shortest / 4, std::chrono::milliseconds{5}, std::chrono::milliseconds{250});
}

// The peer last heard from us up to a keepalive interval before we stopped running, and declares
// the link dead dead_after after that: a pause this long may already have cost us the link.
Clock::duration SessionCore::peer_patience() const {
  return std::max<Clock::duration>(options_.dead_after - options_.keepalive_interval,
                                   2 * tick_period());
}

// ---------------------------------------------------------------------------------------------
// Input.

void SessionCore::on_message(std::span<const std::uint8_t> bytes, TimePoint now) {
  if (closing_ || closing_after_flush_ || !refusal_.empty()) return;
  if (auth_) {
    if (auth_->state() != PeerAuthenticator::State::established) {
      return on_handshake_message(bytes, now);
    }
    const AuthCounters before = auth_->counters();
    const auto opened = auth_->open(bytes);
    if (!opened) return on_unopened(bytes, before);
    bytes = *opened;
  }
  if (!accept_input(bytes, now)) return;
  if (!on_control(now)) return;
  if (!peer_hello_ok_ || !ready_) return before_ready(now);
  bool wake = on_acks(now);
  if (inbound_.body_case() == v1::Envelope::kPayload) wake = on_payload(now) || wake;
  if (inbound_.body_case() == v1::Envelope::kKeepalive) wake = on_keepalive(now) || wake;
  // A side that spends seconds on one large read (thousands of frames to write) does not tick
  // meanwhile: its keepalive must not wait for the tick, or the peer declares it dead.
  wake = keepalive_due(now) || wake;
  if (wake && !closed_) shell_.wake_writer();  // once: an idle writer writes at once
}

// Parses `bytes` into inbound_ unless the link is stale or the message malformed.
bool SessionCore::accept_input(std::span<const std::uint8_t> bytes, TimePoint now) {
  if (const char* why = stale_reason(now)) {
    close_stale(why, now);
    return false;
  }
  last_run_ = now;
  if (!inbound_.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    ++counters_.malformed;
    if (!log_.warned_malformed) {
      log_.warned_malformed = true;
      spdlog::warn(
          "backbone: a message from {} is not a valid envelope: dropped (counted; "
          "further ones are only counted)",
          link_.peer_name);
    }
    return false;
  }
  last_rx_ = now;
  return true;
}

// Hello, refusal and hello requests; false when the message has been dealt with.
bool SessionCore::on_control(TimePoint now) {
  switch (inbound_.body_case()) {
    case v1::Envelope::kHello:
      on_hello(inbound_, now);
      return false;
    case v1::Envelope::kRefusal:
      on_refusal();
      return false;
    case v1::Envelope::kAuth:
      if (auth_) {
        protocol_error("a handshake step inside a sealed envelope");
        return false;
      }
      auth_failed(counters_.auth_failed_unauthenticated,
                  "it wants the challenge-response, which this side is not configured for");
      return false;
    case v1::Envelope::kKeepalive:
      if (!inbound_.keepalive().hello_please()) return true;
      // The peer reopened its end of a line we still had open: it needs our hello again.
      if (initiator_ && stream_) {
        hello_sent_ = false;
        shell_.wake_writer();
      }
      return false;
    default:
      return true;
  }
}

void SessionCore::on_refusal() {
  ++counters_.refusals_received;
  const std::string text = fmt::format("{} refused this {}: {} ({})", link_.peer_name,
                                       role_name(identity_.role), inbound_.refusal().detail(),
                                       v1::Refusal::Reason_Name(inbound_.refusal().reason()));
  bool repeated = false;
  if (stream_) {
    repeated = stream_->last_refusal_ == text;
    stream_->last_refusal_ = text;
  } else {
    repeated = same_as_last_refusal(text);
  }
  spdlog::log(repeated ? spdlog::level::debug : spdlog::level::err, "backbone: {}", text);
  // Its client backs off as after a failed attempt: the same hello would be refused again.
  close(make_error_code(errc::refused_by_peer));
}

void SessionCore::before_ready(TimePoint now) {
  // A new TCP connection starts with a hello, so anything else is a broken peer. On a serial
  // line the peer may still be on its previous link (it has not noticed we reopened): ask it
  // for a hello instead of closing, at most once per keepalive interval.
  if (!link_.crc_framed) return protocol_error("message before the hello");
  ++counters_.before_hello;
  if (!initiator_ && now - last_hello_request_ >= options_.keepalive_interval) {
    last_hello_request_ = now;
    hello_please_owed_ = true;
    shell_.wake_writer();
  }
}

// Applies the ack and any resend request; true when something may be written now.
bool SessionCore::on_acks(TimePoint now) {
  ReliableSender& sender = stream_->sender_;
  const std::size_t unacked = sender.unacked_count();
  if (inbound_.ack() != 0) sender.on_ack(inbound_.ack(), now);
  bool wake = sender.unacked_count() != unacked;  // room freed: the producer may go on
  if (inbound_.resend()) {
    // Selective repeat: only what the peer names as missing goes again.
    if (sender.on_resend_request(inbound_.ack(), now, resend_interval())) wake = true;
    for (std::uint64_t seq : inbound_.missing()) {
      if (sender.on_nack(seq, now, resend_interval())) wake = true;
    }
  }
  return wake;
}

// A keepalive names the last reliable seq the peer wrote: a tail lost on the line (nothing came
// after it to show a gap) is asked for now, not after the peer's retransmission timeout.
bool SessionCore::on_keepalive(TimePoint now) {
  ReliableReceiver& receiver = stream_->receiver_;
  receiver.note_sent_through(inbound_.keepalive().sent_through());
  if (!receiver.should_request_resend(now, resend_interval())) return false;
  ++counters_.resend_requests;
  resend_owed_ = true;
  return true;
}

// Delivers the payload; true when an ack or resend request may be owed.
bool SessionCore::on_payload(TimePoint now) {
  const std::span<const std::uint8_t> view = bytes_of(inbound_.payload());
  if (inbound_.seq() == 0) {
    on_unreliable_payload(view);
    return false;
  }
  on_reliable_payload(view, now);
  return true;
}

void SessionCore::on_unreliable_payload(std::span<const std::uint8_t> view) {
  ++counters_.unreliable_delivered;
  // Process data is never resent: a gap in its numbering is what the line lost.
  if (const std::uint64_t useq = inbound_.unreliable_seq(); useq != 0) {
    if (useq > stream_->unreliable_seen_ + 1) {
      counters_.unreliable_lost += useq - stream_->unreliable_seen_ - 1;
    }
    stream_->unreliable_seen_ = std::max(stream_->unreliable_seen_, useq);
  }
  if (stream_->handlers_.on_payload) stream_->handlers_.on_payload(view, false);
}

void SessionCore::on_reliable_payload(std::span<const std::uint8_t> view, TimePoint now) {
  ReliableReceiver& receiver = stream_->receiver_;
  switch (receiver.accept(inbound_.seq(), inbound_.payload())) {
    case ReliableReceiver::Verdict::deliver:
      ack_owed_ = true;
      deliver_reliable(view);
      // What arrived after a gap that this payload closed follows, in order.
      receiver.drain([&](std::string&& buffered) { deliver_reliable(bytes_of(buffered)); });
      break;
    case ReliableReceiver::Verdict::duplicate:
      ++counters_.reliable_duplicates;
      ack_owed_ = true;  // our ack may have been lost: repeat it
      break;
    case ReliableReceiver::Verdict::buffered:
    case ReliableReceiver::Verdict::gap:
      break;
  }
  if (receiver.should_request_resend(now, resend_interval())) {
    ++counters_.resend_requests;
    resend_owed_ = true;
  }
}

// A reliable payload in order: an empty one is a tombstone (the sender gave it up), not data.
void SessionCore::deliver_reliable(std::span<const std::uint8_t> payload) {
  if (payload.empty()) {
    ++counters_.tombstones_received;
    return;
  }
  ++counters_.reliable_delivered;
  if (stream_->handlers_.on_payload) stream_->handlers_.on_payload(payload, true);
}

// ---------------------------------------------------------------------------------------------
// Hello.

void SessionCore::on_hello(const v1::Envelope& envelope, TimePoint now) {
  const v1::Hello& h = envelope.hello();
  if (peer_hello_ok_) return on_hello_again(envelope, now);
  if (!check_hello(h)) return;
  const BindResult bound = shell_.bind(h);
  if (!bound.stream) return refuse(bound.reason, bound.detail, bound.repeated);
  stream_ = bound.stream;
  adopt_peer_session(h);
  // The peer's ack counts only if it refers to this process's stream.
  if (h.resume_session_id() == identity_.session_id && envelope.ack() != 0) {
    stream_->sender_.on_ack(envelope.ack(), now);
  }
  stream_->sender_.on_link_up();
  stream_->sender_.rewind();
  stream_->peer_hello_ = h;
  peer_hello_ok_ = true;
  if (hello_sent_) become_ready();
  if (!closed_) shell_.wake_writer();  // our hello (if not out yet), then what waited for the link
}

void SessionCore::on_hello_again(const v1::Envelope& envelope, TimePoint now) {
  const v1::Hello& h = envelope.hello();
  if (h.session_id() != stream_->peer_session_id_ || h.name() != stream_->peer_hello_.name()) {
    return protocol_error("second hello, from another peer: " + describe_peer(h));
  }
  // The same peer started its handshake again: our hello was lost, or it reopened its end of
  // a serial line. Settle what it acknowledges, resend the rest, and (as the responder)
  // answer with our hello.
  if (h.resume_session_id() == identity_.session_id && envelope.ack() != 0) {
    stream_->sender_.on_ack(envelope.ack(), now);
  }
  stream_->sender_.rewind();
  // It resends all it holds unacknowledged once our hello reaches it, possibly edited (see
  // on_link_closed): what waits here behind a gap is not delivered.
  stream_->receiver_.reset(stream_->receiver_.expected());
  if (!initiator_) hello_sent_ = false;
  // The peer ended the link this one carried (it declared it dead, or stale) before this side
  // noticed, and acted on that end: it dropped what it held for the link (a gateway: the SDO
  // requests waiting for its buses). For the application the link ended and a new one began,
  // so that what the peer dropped is answered here, not left without an answer (issue 27).
  if (ready_) link_ended_unnoticed();
  shell_.wake_writer();
}

void SessionCore::link_ended_unnoticed() {
  spdlog::info("backbone: {} over {} started a new link: the one it replaces counts as closed",
               describe_peer(stream_->peer_hello_), link_.peer_name);
  if (stream_->handlers_.on_down) stream_->handlers_.on_down();
  if (stream_->handlers_.on_up) stream_->handlers_.on_up(stream_->peer_hello_);
}

// Version and role; false (and a refusal on its way) when the peer cannot be served.
bool SessionCore::check_hello(const v1::Hello& h) {
  if (h.protocol_major() != kProtocolMajor) {
    refuse(v1::Refusal::INCOMPATIBLE_VERSION,
           fmt::format("peer {} speaks protocol {}.{}, '{}' speaks {}.{}: incompatible major "
                       "version",
                       describe_peer(h), h.protocol_major(), h.protocol_minor(), identity_.name,
                       kProtocolMajor, kProtocolMinor));
    return false;
  }
  if (h.role() != identity_.expected_peer) {
    refuse(v1::Refusal::WRONG_ROLE,
           fmt::format("peer {} is a {}, '{}' expects a {}", describe_peer(h), role_name(h.role()),
                       identity_.name, role_name(identity_.expected_peer)));
    return false;
  }
  return true;
}

// A hello from a process this stream has not heard from yet: its reliable stream starts afresh.
void SessionCore::adopt_peer_session(const v1::Hello& h) {
  PeerStream& stream = *stream_;
  if (h.session_id() == stream.peer_session_id_) return;
  if (stream.peer_session_id_ != 0) {
    ++counters_.peer_restarts;
    // What the old process was sent and did not acknowledge is not replayed to the new one:
    // tombstones keep our sequence contiguous for its fresh receiver.
    auto& dropped = stream.handlers_.on_reliable_dropped;
    const std::size_t gone = stream.sender_.drop_all([&](const std::string& p) {
      if (dropped) dropped(p, ReliableDrop::peer_restart);
    });
    counters_.reliable_dropped_peer_restart += gone;
    spdlog::warn(
        "backbone: {} restarted (new session): its reliable stream starts afresh; {} "
        "payload(s) unacknowledged by the old process dropped",
        describe_peer(h), gone);
    if (stream.handlers_.on_peer_restart) stream.handlers_.on_peer_restart(h);
  }
  stream.receiver_.reset(h.send_base());
  stream.unreliable_seen_ = 0;
  stream.peer_session_id_ = h.session_id();
}

// Both hellos are through: the link carries the stream from now on. Called as soon as the second
// of the two happens, so data that follows the peer's hello in the same read is not dropped.
void SessionCore::become_ready() {
  ready_ = true;
  stream_->last_refusal_.clear();  // a refusal after this link is news again
  ++counters_.links;
  // Another link still carries the stream: the peer gave up on it (a silent TCP connection it
  // declared dead) before this side noticed. Closing it below is no news to the application
  // (that link no longer carries the stream), so its end is told here, before the new link's
  // start: the peer dropped what it held for it (issue 27).
  const bool replaces_live_link = stream_->link_ != nullptr;
  if (replaces_live_link) {
    spdlog::info(
        "backbone: {} started a new link while one still carried its stream: that one "
        "counts as closed",
        describe_peer(stream_->peer_hello_));
    stream_->receiver_.reset(stream_->receiver_.expected());
    if (stream_->handlers_.on_down) stream_->handlers_.on_down();
  }
  shell_.carry(*stream_);
  if (stream_->input_paused_) shell_.pause_reading(true);
  const v1::Hello& peer = stream_->peer_hello_;
  spdlog::info(
      "backbone: {} '{}' ready over {} (protocol {}.{}; resuming: {} unacked to resend, next "
      "expected {})",
      role_name(peer.role()), peer.name(), link_.peer_name, peer.protocol_major(),
      peer.protocol_minor(), stream_->sender_.unacked_count(),
      stream_->receiver_.cumulative_ack() + 1);
  if (stream_->handlers_.on_up) stream_->handlers_.on_up(stream_->peer_hello_);
}

void SessionCore::refuse(v1::Refusal::Reason reason, const std::string& detail, bool repeated) {
  ++counters_.refusals_sent;
  const bool same = same_as_last_refusal(detail);
  spdlog::log(repeated || same ? spdlog::level::debug : spdlog::level::err,
              "backbone: refusing {}: {}", link_.peer_name, detail);
  scratch_.Clear();
  v1::Refusal& r = *scratch_.mutable_refusal();
  // A peer that proved nothing learns only that it was refused: the names, versions and modules
  // in use stay in this side's log (a plain link, or one refused before its proof).
  const bool proven = !link_.proven_peer.empty() || !authenticated_peer_.empty();
  r.set_reason(proven ? reason : v1::Refusal::REASON_UNSPECIFIED);
  r.set_detail(proven ? detail : "refused");
  refusal_.clear();
  append_message(refusal_, scratch_);
  shell_.wake_writer();
}

void SessionCore::protocol_error(const std::string& why) {
  ++counters_.protocol_errors;
  // Once per side at error level: a flood of peers breaking the protocol is counted, not logged.
  const bool first = !log_.warned_protocol_error;
  log_.warned_protocol_error = true;
  spdlog::log(first ? spdlog::level::err : spdlog::level::debug,
              "backbone: protocol error on {}: {}; closing the link{}", link_.peer_name, why,
              first ? " (first occurrence; further ones are only counted)" : "");
  close(make_error_code(errc::closed));
}

// A refused gateway retries with backoff and is refused again, for as long as the configuration
// stays wrong: the first refusal is an error, the same one again only a debug line (the stats
// line counts them all).
bool SessionCore::same_as_last_refusal(const std::string& text) {
  if (text == log_.last_refusal) return true;
  log_.last_refusal = text;
  return false;
}

// ---------------------------------------------------------------------------------------------
// Authentication: gateway challenge; surface challenge and proof; gateway proof. Then sealed.

// Before the handshake completes: its steps, a refusal, a hello request; nothing else counts.
void SessionCore::on_handshake_message(std::span<const std::uint8_t> bytes, TimePoint now) {
  if (const char* why = stale_reason(now)) return close_stale(why, now);
  last_run_ = now;
  // Sealed messages from a peer still on its previous link do not parse (their counter comes
  // first); neither does line noise.
  if (!inbound_.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    return before_handshake(now);
  }
  switch (inbound_.body_case()) {
    case v1::Envelope::kAuth:
      last_rx_ = now;
      return on_auth_step();
    case v1::Envelope::kRefusal:
      last_rx_ = now;
      return on_refusal();
    case v1::Envelope::kKeepalive:
      if (!inbound_.keepalive().hello_please()) return before_handshake(now);
      // A surface that reopened its end asks: our challenge goes again.
      if (auth_->state() == PeerAuthenticator::State::challenged) {
        auth_step_ = last_auth_step_;
        shell_.wake_writer();
      }
      return;
    case v1::Envelope::kHello:
      return auth_failed(counters_.auth_failed_unauthenticated,
                         "its hello came without the challenge-response this side requires (is "
                         "authentication configured at both ends?)");
    default:
      return before_handshake(now);
  }
}

// Something else than a handshake step before the handshake completed. On a serial line the
// peer may still be on its previous, authenticated link: as the responder, ask it for a new
// start (it closes that link and challenges again). Elsewhere the peer skipped authentication.
void SessionCore::before_handshake(TimePoint now) {
  if (!link_.crc_framed) {
    return auth_failed(counters_.auth_failed_unauthenticated,
                       "it sent something else than the challenge-response this side requires");
  }
  ++counters_.before_hello;
  if (!initiator_ && now - last_hello_request_ >= options_.keepalive_interval) {
    last_hello_request_ = now;
    hello_please_owed_ = true;
    shell_.wake_writer();
  }
}

void SessionCore::on_auth_step() {
  using State = PeerAuthenticator::State;
  const v1::AuthStep& step = inbound_.auth();
  const bool challenge = !step.challenge().empty();
  const bool proof = !step.proof().empty();
  const AuthCounters before = auth_->counters();
  if (auth_->role() == AuthRole::surface) {
    if (challenge && !proof) return answer_challenge(step.challenge());
    if (proof && !challenge && auth_->state() == State::responded) {
      if (!auth_->verify(bytes_of(step.proof()))) {
        return auth_failed(before, "its proof is wrong (another key?)");
      }
      return auth_established();
    }
  } else if (challenge && proof && auth_->state() == State::challenged) {
    const auto own_proof = auth_->respond(bytes_of(step.challenge()));
    if (!own_proof) return auth_failed(before, "its challenge is unusable");
    if (!auth_->verify(bytes_of(step.proof()))) {
      return auth_failed(before, "its proof is wrong (another key?)");
    }
    queue_auth_step({}, *own_proof);
    return auth_established();  // our hello follows the proof, sealed
  }
  auth_failed(counters_.auth_failed_malformed, "a handshake step out of order");
}

// Surface: the gateway's challenge, answered with ours and our proof.
void SessionCore::answer_challenge(const std::string& challenge) {
  using State = PeerAuthenticator::State;
  if (auth_->state() == State::responded) {
    if (challenge == answered_challenge_) {
      auth_step_ = last_auth_step_;  // our answer was lost: the gateway asks again
      shell_.wake_writer();
      return;
    }
    // The gateway started over (it reopened its end): so do we, with new nonces.
    auth_ = options_.authenticator(link_.peer_name);
  }
  const AuthCounters before = auth_->counters();
  const auto own_challenge = auth_->make_challenge();
  if (!own_challenge) return auth_failed(before, "no challenge (random source failed)");
  const auto proof = auth_->respond(bytes_of(challenge));
  if (!proof) return auth_failed(before, "its challenge is unusable");
  answered_challenge_ = challenge;
  queue_auth_step(*own_challenge, *proof);
}

void SessionCore::queue_auth_step(std::span<const std::uint8_t> challenge,
                                  std::span<const std::uint8_t> proof) {
  scratch_.Clear();
  v1::AuthStep& step = *scratch_.mutable_auth();
  if (!challenge.empty()) step.set_challenge(challenge.data(), challenge.size());
  if (!proof.empty()) step.set_proof(proof.data(), proof.size());
  last_auth_step_.clear();
  append_message(last_auth_step_, scratch_);
  auth_step_ = last_auth_step_;
  shell_.wake_writer();
}

void SessionCore::auth_established() {
  ++counters_.auth_established;
  authenticated_peer_ = auth_->peer_identity();
  spdlog::info("backbone: {} proved to be '{}' (challenge-response); envelopes sealed from now on",
               link_.peer_name, authenticated_peer_);
  shell_.wake_writer();  // the gateway's hello, sealed
}

// The authenticator's verdict, counted by what it found.
void SessionCore::auth_failed(const AuthCounters& before, const std::string& why) {
  const AuthCounters& after = auth_->counters();
  if (after.unknown_keys != before.unknown_keys) {
    return auth_failed(counters_.auth_failed_unknown_key, "its key is not one configured here");
  }
  if (after.bad_proofs != before.bad_proofs) {
    return auth_failed(counters_.auth_failed_bad_proof, why);
  }
  if (after.parameter_mismatches != before.parameter_mismatches) {
    return auth_failed(counters_.auth_failed_malformed, "it uses another MAC size");
  }
  auth_failed(counters_.auth_failed_malformed, why);
}

// The details stay in this side's log: an unproven peer learns only that it was refused.
void SessionCore::auth_failed(std::uint64_t& reason, const std::string& why) {
  ++reason;
  ++counters_.refusals_sent;
  const std::string text = "authentication failed: " + why;
  spdlog::log(same_as_last_refusal(text) ? spdlog::level::debug : spdlog::level::warn,
              "backbone: refusing {}: {} (the peer is told only 'refused'; counted)",
              link_.peer_name, text);
  scratch_.Clear();
  scratch_.mutable_refusal()->set_detail("refused");
  refusal_.clear();
  append_message(refusal_, scratch_);
  shell_.wake_writer();
}

// A message that did not open on an authenticated link. Unsealed control messages are the
// peer's end starting over (a new challenge, a hello request) or refusing: they only end this
// link, which anyone able to write to the line could do anyway. Everything else is dropped.
void SessionCore::on_unopened(std::span<const std::uint8_t> bytes, const AuthCounters& before) {
  const AuthCounters& after = auth_->counters();
  // A sealed message starts with its counter's high byte, zero for the first 2^24 messages,
  // which no envelope does.
  if (inbound_.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    if (inbound_.has_refusal()) return on_refusal();
    if (link_.crc_framed && inbound_.has_auth()) {
      // A repeated answer or proof is late news; a bare challenge is a new start.
      if (inbound_.auth().proof().empty()) return peer_restarted("challenged again");
      return;
    }
    if (link_.crc_framed && inbound_.has_keepalive() && inbound_.keepalive().hello_please()) {
      return peer_restarted("asked for a hello");
    }
  }
  if (after.truncated != before.truncated) {
    ++counters_.rejected_truncated;
  } else if (after.replays != before.replays) {
    ++counters_.rejected_replay;
  } else {
    ++counters_.rejected_bad_tag;
  }
  if (!log_.warned_rejected) {
    log_.warned_rejected = true;
    spdlog::warn(
        "backbone: a sealed envelope from {} did not open (tampered, replayed, reordered or cut "
        "short): dropped (counted by reason; further ones are only counted)",
        link_.peer_name);
  }
}

void SessionCore::peer_restarted(const char* what) {
  ++counters_.auth_restarts;
  spdlog::info(
      "backbone: {} {}: its end of the line started over; closing this link so that the next "
      "one authenticates afresh",
      link_.peer_name, what);
  close(make_error_code(errc::closed));
}

// Each delimited envelope in `plain` goes to `out` as counter | envelope | tag, delimited.
void SessionCore::seal_into(const std::string& plain, std::string& out) {
  DelimitedDecoder decoder;
  decoder.feed(bytes_of(plain), [&](std::span<const std::uint8_t> envelope) {
    std::array<std::uint8_t, kMaxLengthPrefixBytes> prefix{};
    const std::uint8_t* end = write_varint(envelope.size() + auth_->seal_overhead(), prefix.data());
    const std::size_t start = out.size();
    out.append(reinterpret_cast<const char*>(prefix.data()),
               static_cast<std::size_t>(end - prefix.data()));
    // Established, it fails only after 2^64 messages: then nothing more goes out.
    if (!auth_->seal(envelope, out)) out.resize(start);
  });
}

// ---------------------------------------------------------------------------------------------
// Output.

void SessionCore::fill(std::string& out, TimePoint now) {
  if (closing_) return;
  if (!auth_) return fill_envelopes(out, now);
  if (!auth_step_.empty()) {
    out += auth_step_;  // unsealed: the keys come from the handshake
    auth_step_.clear();
    last_tx_ = now;
  }
  // Before the handshake completes only a refusal or a hello request can go out, unsealed.
  if (auth_->state() != PeerAuthenticator::State::established) return fill_envelopes(out, now);
  sealing_.clear();
  fill_envelopes(sealing_, now);
  seal_into(sealing_, out);
}

void SessionCore::fill_envelopes(std::string& out, TimePoint now) {
  if (!fill_control(out, now)) return;
  if (hello_sent_ && peer_hello_ok_ && !ready_) become_ready();
  if (closed_ || !ready_) return;
  fill_stream(out, now);
}

// Refusal, hello request and hello; false when nothing else may follow in this write.
bool SessionCore::fill_control(std::string& out, TimePoint now) {
  if (closing_after_flush_) {
    close(make_error_code(errc::closed));  // the refusal has been written
    return false;
  }
  if (!refusal_.empty()) {
    out += refusal_;
    refusal_.clear();
    closing_after_flush_ = true;
    return false;
  }
  // A writer woken as the process resumes (its buses queued frames meanwhile) may run before the
  // late tick and the reader: its run proves nothing about the freeze, and must not hide it.
  if (now - last_run_ > peer_patience()) {
    close_stale("this side did not run for longer than the peer waits", now);
    return false;
  }
  last_run_ = now;
  if (hello_please_owed_) {
    scratch_.Clear();
    scratch_.mutable_keepalive()->set_hello_please(true);
    append_message(out, scratch_);
    hello_please_owed_ = false;
  }
  const bool proven = !auth_ || auth_->state() == PeerAuthenticator::State::established;
  if (!hello_sent_ && stream_ && proven) write_hello(out, now);
  return true;
}

void SessionCore::write_hello(std::string& out, TimePoint now) {
  scratch_.Clear();
  scratch_.set_ack(stream_->receiver_.cumulative_ack());
  v1::Hello& h = *scratch_.mutable_hello();
  h.set_protocol_major(kProtocolMajor);
  h.set_protocol_minor(kProtocolMinor);
  h.set_role(identity_.role);
  h.set_name(identity_.name);
  for (std::uint32_t id : identity_.module_ids) h.add_module_ids(id);
  h.set_session_id(identity_.session_id);
  h.set_resume_session_id(stream_->peer_session_id_);
  h.set_send_base(stream_->sender_.send_base());
  for (const char* c : {"reliable", "conflation", "priority"}) h.add_capabilities(c);
  h.add_capabilities(link_.crc_framed ? "cobs-crc32c" : "delimited");
  if (!identity_.application.empty()) h.set_application(identity_.application);
  append_message(out, scratch_);
  hello_sent_ = true;
  last_tx_ = now;
}

// Reliable payloads (retransmissions first), whatever the producer adds, and an ack or keepalive
// if nothing else.
void SessionCore::fill_stream(std::string& out, TimePoint now) {
  drop_too_old(now);
  Writer writer(*this, out, now);
  writer.drain_reliable();
  if (writer.room() > 0 && stream_->handlers_.produce) stream_->handlers_.produce(writer);
  if (resend_owed_ || (!writer.wrote() && (ack_owed_ || keepalive_owed_))) {
    append_keepalive_envelope(out, next_header(0, 0), stream_->sender_.highest_sent());
    ++counters_.keepalives_sent;
  }
  if (writer.wrote()) {
    last_tx_ = now;
    keepalive_owed_ = false;
  }
}

// What the next envelope carries: always the current ack, and the resend request if one is owed.
EnvelopeHeader SessionCore::next_header(std::uint64_t seq, std::uint64_t unreliable_seq) {
  EnvelopeHeader header{.seq = seq,
                        .ack = stream_->receiver_.cumulative_ack(),
                        .resend = resend_owed_,
                        .missing = {},
                        .unreliable_seq = unreliable_seq};
  if (resend_owed_) {
    // The first hole is ack + 1 (implied); list the further ones.
    missing_ = stream_->receiver_.missing(kMaxMissingListed + 1);
    if (!missing_.empty()) header.missing = std::span(missing_).subspan(1);
  }
  resend_owed_ = ack_owed_ = false;
  return header;
}

// ---------------------------------------------------------------------------------------------
// Time.

void SessionCore::on_tick(TimePoint now, bool reading_paused, bool bytes_arrived) {
  if (closing_) return;  // closing already (its handler may come later)
  last_tick_ = now;
  const bool did_not_run = now - last_run_ > peer_patience();
  // This side did not run for longer than the peer waits: the peer may have declared the link
  // dead meanwhile and told its users that what it sent failed. Whatever was heard before the
  // freeze, arrived since (counted before the process stopped, or read as it resumed) or waits
  // unread proves nothing now; only a link silent all along is merely dead.
  if (did_not_run && (now - last_rx_ <= options_.dead_after || bytes_arrived || reading_paused ||
                      shell_.input_waiting())) {
    return close_stale("this side did not run for longer than the peer waits", now);
  }
  last_run_ = now;
  // Not reading (PeerStream::pause_input): the silence is ours, and so are the missing acks.
  if (reading_paused) last_rx_ = now;
  if (bytes_arrived) last_rx_ = now;  // part of a message: the peer is sending
  if (now - last_rx_ > options_.dead_after && shell_.input_waiting()) {
    // The peer did send: this side was too busy to read it (the tick comes late, or before the
    // reader's turn). Unless it was busy for longer than the peer waits, the link is alive.
    const char* why = "this side did not run for longer than the peer waits";
    if (did_not_run) return close_stale(why, now);
    last_rx_ = now;
  }
  if (now - last_rx_ > options_.dead_after) {
    ++counters_.dead_links;
    spdlog::warn("backbone: nothing from {} for {} ms: link dead, closing it", link_.peer_name,
                 ms(now - last_rx_));
    return close(make_error_code(errc::closed));
  }
  if (initiator_ && !ready_ && hello_sent_ && now - last_tx_ >= options_.keepalive_interval) {
    hello_sent_ = false;  // no answer yet: the hello may have been lost on a noisy line
    shell_.wake_writer();
  }
  if (auth_ && auth_->state() == PeerAuthenticator::State::challenged &&
      now - last_tx_ >= options_.keepalive_interval) {
    auth_step_ = last_auth_step_;  // no answer yet: the challenge may have been lost too
    shell_.wake_writer();
  }
  if (ready_) tick_ready(now, reading_paused);
}

void SessionCore::tick_ready(TimePoint now, bool deaf) {
  bool wake = false;
  if (!deaf && stream_->sender_.retransmit_due(now, options_.retransmit_timeout)) {
    stream_->sender_.on_retransmit_timeout();  // the oldest alone, or go back N
    wake = true;
  }
  // A resend request (or the message it asked for) can be lost too: ask again.
  if (stream_->receiver_.should_request_resend(now, resend_interval())) {
    ++counters_.resend_requests;
    resend_owed_ = true;
    wake = true;
  }
  if (now - last_tx_ >= options_.keepalive_interval) {
    keepalive_owed_ = true;
    wake = true;
  }
  if (wake) shell_.wake_writer();
}

bool SessionCore::keepalive_due(TimePoint now) {
  if (!ready_ || keepalive_owed_ || now - last_tx_ < options_.keepalive_interval) return false;
  keepalive_owed_ = true;
  return true;
}

// The tick closes a link silent for dead_after within one period, and this side sends at least
// every keepalive interval. Input that finds either broken arrives after the tick could not run
// (the process was stopped, or not scheduled): the peer may meanwhile have declared the link dead
// and told its users that what it sent failed, so none of it may be acted on now.
const char* SessionCore::stale_reason(TimePoint now) const {
  if (now - last_rx_ > options_.dead_after) return "nothing received for longer than dead_after";
  if (now - last_run_ > peer_patience()) {
    return "this side did not run for longer than the peer waits";
  }
  return nullptr;
}

void SessionCore::close_stale(const char* why, TimePoint now) {
  ++counters_.stale_links_closed;
  spdlog::warn(
      "backbone: link to {} stale ({}: {} ms since the last input, {} ms since this side last "
      "ran): what arrived is not delivered, closing the link; the stream resumes on the next one",
      link_.peer_name, why, ms(now - last_rx_), ms(now - last_run_));
  close(make_error_code(errc::closed));
}

void SessionCore::drop_too_old(TimePoint now) {
  if (options_.reliable_max_age.count() <= 0) return;
  auto& dropped = stream_->handlers_.on_reliable_dropped;
  // A payload sent before it expired may have arrived, its ack merely late: counted apart, or a
  // slow ack would count as a drop a frame the peer delivered.
  stream_->sender_.drop_older_than(
      now - options_.reliable_max_age, [&](const std::string& p, bool sent) {
        ++(sent ? counters_.reliable_expired_unacked : counters_.reliable_dropped_too_old);
        if (dropped) dropped(p, sent ? ReliableDrop::too_old_unacked : ReliableDrop::too_old);
      });
}

}  // namespace canbridge::backbone
