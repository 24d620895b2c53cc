#include "backbone/session.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <random>

#include "backbone/delimited_codec.hpp"

namespace canbridge::backbone {

namespace {

using Clock = std::chrono::steady_clock;

// Envelope field tags (field number << 3 | wire type), for the hot path that writes envelopes
// by hand around a stored payload instead of copying it into a message object first.
constexpr std::uint8_t kTagSeq = (v1::Envelope::kSeqFieldNumber << 3) | 0;
constexpr std::uint8_t kTagAck = (v1::Envelope::kAckFieldNumber << 3) | 0;
constexpr std::uint8_t kTagResend = (v1::Envelope::kResendFieldNumber << 3) | 0;
constexpr std::uint8_t kTagKeepalive = (v1::Envelope::kKeepaliveFieldNumber << 3) | 2;
constexpr std::uint8_t kTagPayload = (v1::Envelope::kPayloadFieldNumber << 3) | 2;
constexpr std::uint8_t kTagMissing = (v1::Envelope::kMissingFieldNumber << 3) | 2;  // packed
constexpr std::uint8_t kTagUnreliableSeq = (v1::Envelope::kUnreliableSeqFieldNumber << 3) | 0;
// Holes listed in one resend request: enough to repair a burst in one round trip.
constexpr std::size_t kMaxMissingListed = 16;

std::size_t varint_length(std::uint64_t value) {
  std::size_t n = 1;
  while (value >= 0x80) {
    value >>= 7;
    ++n;
  }
  return n;
}

void put_varint(std::string& out, std::uint64_t value) {
  while (value >= 0x80) {
    out.push_back(static_cast<char>((value & 0x7F) | 0x80));
    value >>= 7;
  }
  out.push_back(static_cast<char>(value));
}

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

}  // namespace

// A refused gateway retries with backoff and is refused again, for as long as the configuration
// stays wrong: the first refusal is an error, the same one again only a debug line (the stats
// line counts them all).
bool SessionLink::same_as_last_refusal(const std::string& text) {
  if (text == log_.last_refusal) return true;
  log_.last_refusal = text;
  return false;
}

std::uint64_t random_session_id() {
  std::random_device device;
  std::uint64_t id = 0;
  while (id == 0) id = (std::uint64_t{device()} << 32) ^ device();
  return id;
}

std::string describe_peer(const v1::Hello& hello) {
  return "'" + hello.name() + "' (" + role_name(hello.role()) + ", protocol " +
         std::to_string(hello.protocol_major()) + "." + std::to_string(hello.protocol_minor()) +
         ")";
}

// ---------------------------------------------------------------------------------------------
PeerStream::PeerStream(const SessionOptions& options, Handlers handlers)
    : sender_(ReliableSender::Options{options.resend_buffer_messages, options.resend_buffer_bytes}),
      // The reorder buffer matches the peer's send window (both ends use the same tuning), so
      // everything in flight behind a lost message is kept, not resent.
      receiver_(options.resend_buffer_messages, options.resend_buffer_bytes),
      handlers_(std::move(handlers)) {}

void PeerStream::wake() {
  if (link_) link_->message_link()->wake_writer();
}

void PeerStream::close_link() {
  if (link_) link_->close();
}

void PeerStream::pause_input(bool paused) {
  input_paused_ = paused;
  if (link_) link_->message_link()->pause_reading(paused);
}

// ---------------------------------------------------------------------------------------------
// The producer's view of one write: what fits, and where payloads go.
class SessionLink::Writer final : public PayloadSink {
 public:
  Writer(SessionLink& session, std::string& out, Clock::time_point now)
      : session_(session), out_(out), start_(out.size()), now_(now) {}

  std::size_t room() const override {
    const std::size_t used = out_.size() - start_;
    return used >= session_.options_.max_write_bytes ? 0 : session_.options_.max_write_bytes - used;
  }
  bool reliable_room(std::size_t bytes) const override {
    return session_.stream_->sender_.can_accept(bytes);
  }
  void send_reliable(std::string payload) override {
    send_reliable_since(std::move(payload), now_);
  }
  void send_reliable_since(std::string payload, Clock::time_point born) override {
    const auto max_age = session_.options_.reliable_max_age;
    if (max_age.count() > 0 && now_ - born > max_age) {
      // Too old already: never sequenced, never sent.
      ++session_.counters_.reliable_dropped_too_old;
      auto& dropped = session_.stream_->handlers_.on_reliable_dropped;
      if (dropped) dropped(payload, ReliableDrop::too_old);
      return;
    }
    // Counted by the sender when refused.
    if (!session_.stream_->sender_.push(std::move(payload), std::min(born, now_))) return;
    drain_reliable();
  }
  Clock::time_point now() const override { return now_; }
  void send_unreliable(std::span<const std::uint8_t> payload) override {
    session_.append_envelope(out_, 0, payload, false, ++session_.stream_->unreliable_sent_);
    ++session_.counters_.unreliable_sent;
  }

  // Sends what the resend buffer holds and this link has not carried yet, as room allows.
  void drain_reliable() {
    ReliableSender& sender = session_.stream_->sender_;
    while (room() > 0) {
      auto next = sender.next_to_send(now_);
      if (!next) break;
      session_.append_envelope(
          out_, next->seq,
          {reinterpret_cast<const std::uint8_t*>(next->payload.data()), next->payload.size()},
          false);
      ++(next->retransmission ? session_.counters_.reliable_resent
                              : session_.counters_.reliable_sent);
    }
  }

  bool wrote() const { return out_.size() != start_; }

 private:
  SessionLink& session_;
  std::string& out_;
  std::size_t start_;
  Clock::time_point now_;
};

// ---------------------------------------------------------------------------------------------
std::shared_ptr<SessionLink> SessionLink::create(std::shared_ptr<MessageLink> link,
                                                 const Identity& identity,
                                                 const SessionOptions& options, PeerStream* preset,
                                                 Binder binder, SessionCounters& counters,
                                                 SessionLogMemory* log) {
  return std::shared_ptr<SessionLink>(new SessionLink(std::move(link), identity, options, preset,
                                                      std::move(binder), counters, log));
}

SessionLink::SessionLink(std::shared_ptr<MessageLink> link, const Identity& identity,
                         const SessionOptions& options, PeerStream* preset, Binder binder,
                         SessionCounters& counters, SessionLogMemory* log)
    : link_(std::move(link)),
      identity_(identity),
      options_(options),
      stream_(preset),
      initiator_(preset != nullptr),
      binder_(std::move(binder)),
      counters_(counters),
      log_(log ? *log : own_log_),
      watchdog_(link_->executor()) {}

SessionLink::~SessionLink() = default;

void SessionLink::start() {
  last_rx_ = last_tx_ = last_run_ = now();
  std::weak_ptr<SessionLink> weak = weak_from_this();
  link_->start(
      [weak](std::span<const std::uint8_t> bytes) {
        if (auto self = weak.lock()) self->on_message(bytes);
      },
      [weak](std::string& out) {
        if (auto self = weak.lock()) self->fill(out);
      },
      [weak](std::error_code) {
        if (auto self = weak.lock()) self->on_closed();
      });
  arm_watchdog();
  link_->wake_writer();  // a preset stream's hello goes out at once
}

void SessionLink::close() {
  link_->close();
}

void SessionLink::append_envelope(std::string& out, std::uint64_t seq,
                                  std::span<const std::uint8_t> payload, bool keepalive,
                                  std::uint64_t unreliable_seq) {
  const std::uint64_t ack = stream_->receiver_.cumulative_ack();
  const bool resend = resend_owed_;
  std::size_t missing_bytes = 0;
  if (resend) {
    // The first hole is ack + 1 (implied); list the further ones.
    missing_ = stream_->receiver_.missing(kMaxMissingListed + 1);
    if (!missing_.empty()) missing_.erase(missing_.begin());
    for (std::uint64_t m : missing_) missing_bytes += varint_length(m);
  }
  std::size_t size = 0;
  if (seq != 0) size += 1 + varint_length(seq);
  if (ack != 0) size += 1 + varint_length(ack);
  if (resend) size += 2;
  if (missing_bytes != 0) size += 1 + varint_length(missing_bytes) + missing_bytes;
  if (unreliable_seq != 0) size += 1 + varint_length(unreliable_seq);
  size += keepalive ? 2 : 1 + varint_length(payload.size()) + payload.size();
  put_varint(out, size);
  if (seq != 0) {
    out.push_back(static_cast<char>(kTagSeq));
    put_varint(out, seq);
  }
  if (ack != 0) {
    out.push_back(static_cast<char>(kTagAck));
    put_varint(out, ack);
  }
  if (resend) {
    out.push_back(static_cast<char>(kTagResend));
    out.push_back(1);
    resend_owed_ = false;
  }
  if (missing_bytes != 0) {
    out.push_back(static_cast<char>(kTagMissing));
    put_varint(out, missing_bytes);
    for (std::uint64_t m : missing_) put_varint(out, m);
  }
  if (unreliable_seq != 0) {
    out.push_back(static_cast<char>(kTagUnreliableSeq));
    put_varint(out, unreliable_seq);
  }
  if (keepalive) {
    out.push_back(static_cast<char>(kTagKeepalive));
    out.push_back(0);
  } else {
    out.push_back(static_cast<char>(kTagPayload));
    put_varint(out, payload.size());
    out.append(reinterpret_cast<const char*>(payload.data()), payload.size());
  }
  ack_owed_ = false;  // every envelope carries the current ack
}

// Called by the link's writer whenever it can send: hello, refusal, then reliable payloads
// (retransmissions first), whatever the producer adds, and an ack or keepalive if nothing else.
void SessionLink::fill(std::string& out) {
  if (closed_) return;
  if (closing_after_flush_) {
    link_->close();  // the refusal has been written
    return;
  }
  if (!refusal_.empty()) {
    out += refusal_;
    refusal_.clear();
    closing_after_flush_ = true;
    return;
  }
  const Clock::time_point now = this->now();
  last_run_ = now;
  if (hello_please_owed_) {
    scratch_.Clear();
    scratch_.mutable_keepalive()->set_hello_please(true);
    append_message(out, scratch_);
    hello_please_owed_ = false;
  }
  if (!hello_sent_ && stream_) {
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
    h.add_capabilities(link_->crc_framed() ? "cobs-crc32c" : "delimited");
    if (!identity_.application.empty()) h.set_application(identity_.application);
    append_message(out, scratch_);
    hello_sent_ = true;
    last_tx_ = now;
  }
  if (hello_sent_ && peer_hello_ok_ && !ready_) become_ready();
  if (closed_) return;
  if (!ready_) return;
  drop_too_old(now);
  Writer writer(*this, out, now);
  writer.drain_reliable();
  if (writer.room() > 0 && stream_->handlers_.produce) stream_->handlers_.produce(writer);
  if (resend_owed_ || (!writer.wrote() && (ack_owed_ || keepalive_owed_))) {
    append_envelope(out, 0, {}, true);
    ++counters_.keepalives_sent;
  }
  if (writer.wrote()) {
    last_tx_ = now;
    keepalive_owed_ = false;
  }
}

// Both hellos are through: the link carries the stream from now on. Called as soon as the second
// of the two happens, so data that follows the peer's hello in the same read is not dropped.
void SessionLink::become_ready() {
  ready_ = true;
  stream_->last_refusal_.clear();  // a refusal after this link is news again
  ++counters_.links;
  if (stream_->link_ && stream_->link_.get() != this) stream_->link_->close();  // stale link
  stream_->link_ = shared_from_this();
  if (stream_->input_paused_) link_->pause_reading(true);
  const v1::Hello& peer = stream_->peer_hello_;
  spdlog::info(
      "backbone: {} '{}' ready over {} (protocol {}.{}; resuming: {} unacked to resend, next "
      "expected {})",
      role_name(peer.role()), peer.name(), link_->peer_name(), peer.protocol_major(),
      peer.protocol_minor(), stream_->sender_.unacked_count(),
      stream_->receiver_.cumulative_ack() + 1);
  if (stream_->handlers_.on_up) stream_->handlers_.on_up(stream_->peer_hello_);
}

Clock::time_point SessionLink::now() const {
  return options_.clock ? options_.clock() : Clock::now();
}

// The watchdog closes a link silent for dead_after within one tick, and this side sends at least
// every keepalive interval. Input that finds either broken arrives after the watchdog could not
// run (the process was stopped, or not scheduled): the peer may meanwhile have declared the link
// dead and told its users that what it sent failed, so none of it may be acted on now.
const char* SessionLink::stale_reason(Clock::time_point now) const {
  if (now - last_rx_ > options_.dead_after) return "nothing received for longer than dead_after";
  if (now - last_run_ > peer_patience())
    return "this side did not run for longer than the peer waits";
  return nullptr;
}

// The peer last heard from us up to a keepalive interval before we stopped running, and declares
// the link dead dead_after after that: a pause this long may already have cost us the link.
std::chrono::steady_clock::duration SessionLink::peer_patience() const {
  return std::max<Clock::duration>(options_.dead_after - options_.keepalive_interval,
                                   2 * watchdog_tick());
}

void SessionLink::close_stale(const char* why, Clock::time_point now) {
  ++counters_.stale_links_closed;
  spdlog::warn(
      "backbone: link to {} stale ({}: {} ms since the last input, {} ms since this side last "
      "ran): what arrived is not delivered, closing the link; the stream resumes on the next one",
      link_->peer_name(), why,
      std::chrono::duration_cast<std::chrono::milliseconds>(now - last_rx_).count(),
      std::chrono::duration_cast<std::chrono::milliseconds>(now - last_run_).count());
  link_->close();
}

// A reliable payload in order: an empty one is a tombstone (the sender gave it up), not data.
void SessionLink::deliver_reliable(std::span<const std::uint8_t> payload) {
  if (payload.empty()) {
    ++counters_.tombstones_received;
    return;
  }
  ++counters_.reliable_delivered;
  if (stream_->handlers_.on_payload) stream_->handlers_.on_payload(payload, true);
}

void SessionLink::drop_too_old(Clock::time_point now) {
  if (options_.reliable_max_age.count() <= 0) return;
  auto& dropped = stream_->handlers_.on_reliable_dropped;
  counters_.reliable_dropped_too_old +=
      stream_->sender_.drop_older_than(now - options_.reliable_max_age, [&](const std::string& p) {
        if (dropped) dropped(p, ReliableDrop::too_old);
      });
}

void SessionLink::on_message(std::span<const std::uint8_t> bytes) {
  if (closed_ || closing_after_flush_ || !refusal_.empty()) return;
  const Clock::time_point now = this->now();
  if (const char* why = stale_reason(now)) return close_stale(why, now);
  last_run_ = now;
  if (!inbound_.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    ++counters_.malformed;
    if (!log_.warned_malformed) {
      log_.warned_malformed = true;
      spdlog::warn(
          "backbone: a message from {} is not a valid envelope: dropped (counted; "
          "further ones are only counted)",
          link_->peer_name());
    }
    return;
  }
  last_rx_ = now;
  switch (inbound_.body_case()) {
    case v1::Envelope::kHello:
      return on_hello(inbound_);
    case v1::Envelope::kRefusal: {
      ++counters_.refusals_received;
      const std::string text = fmt::format("{} refused this {}: {} ({})", link_->peer_name(),
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
      return link_->close(make_error_code(errc::refused_by_peer));
    }
    case v1::Envelope::kKeepalive:
      if (inbound_.keepalive().hello_please()) {
        // The peer reopened its end of a line we still had open: it needs our hello again.
        if (initiator_ && stream_) {
          hello_sent_ = false;
          link_->wake_writer();
        }
        return;
      }
      break;
    default:
      break;
  }
  if (!peer_hello_ok_ || !ready_) {
    // A new TCP connection starts with a hello, so anything else is a broken peer. On a serial
    // line the peer may still be on its previous link (it has not noticed we reopened): ask it
    // for a hello instead of closing, at most once per keepalive interval.
    if (!link_->crc_framed()) return protocol_error("message before the hello");
    ++counters_.before_hello;
    if (!initiator_ && now - last_hello_request_ >= options_.keepalive_interval) {
      last_hello_request_ = now;
      hello_please_owed_ = true;
      link_->wake_writer();
    }
    return;
  }
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
  if (inbound_.body_case() == v1::Envelope::kPayload) {
    const std::string& payload = inbound_.payload();
    const std::span<const std::uint8_t> view(reinterpret_cast<const std::uint8_t*>(payload.data()),
                                             payload.size());
    if (inbound_.seq() == 0) {
      ++counters_.unreliable_delivered;
      // Process data is never resent: a gap in its numbering is what the line lost.
      if (const std::uint64_t useq = inbound_.unreliable_seq(); useq != 0) {
        if (useq > stream_->unreliable_seen_ + 1) {
          counters_.unreliable_lost += useq - stream_->unreliable_seen_ - 1;
        }
        stream_->unreliable_seen_ = std::max(stream_->unreliable_seen_, useq);
      }
      if (stream_->handlers_.on_payload) stream_->handlers_.on_payload(view, false);
    } else {
      ReliableReceiver& receiver = stream_->receiver_;
      switch (receiver.accept(inbound_.seq(), payload)) {
        case ReliableReceiver::Verdict::deliver: {
          ack_owed_ = true;
          deliver_reliable(view);
          // What arrived after a gap that this payload closed follows, in order.
          receiver.drain([&](std::string&& buffered) {
            deliver_reliable(
                {reinterpret_cast<const std::uint8_t*>(buffered.data()), buffered.size()});
          });
          break;
        }
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
      wake = true;
    }
  }
  if (wake && !closed_) link_->wake_writer();
}

void SessionLink::on_hello(const v1::Envelope& envelope) {
  const v1::Hello& h = envelope.hello();
  if (peer_hello_ok_) {
    if (h.session_id() != stream_->peer_session_id_ || h.name() != stream_->peer_hello_.name()) {
      return protocol_error("second hello, from another peer: " + describe_peer(h));
    }
    // The same peer started its handshake again: our hello was lost, or it reopened its end of
    // a serial line. Settle what it acknowledges, resend the rest, and (as the responder)
    // answer with our hello.
    const Clock::time_point now = this->now();
    if (h.resume_session_id() == identity_.session_id && envelope.ack() != 0) {
      stream_->sender_.on_ack(envelope.ack(), now);
    }
    stream_->sender_.rewind();
    // It resends all it holds unacknowledged once our hello reaches it, possibly edited (see
    // on_closed): what waits here behind a gap is not delivered.
    stream_->receiver_.reset(stream_->receiver_.expected());
    if (!initiator_) hello_sent_ = false;
    link_->wake_writer();
    return;
  }
  if (h.protocol_major() != kProtocolMajor) {
    return refuse(v1::Refusal::INCOMPATIBLE_VERSION,
                  "peer " + describe_peer(h) + " speaks protocol " +
                      std::to_string(h.protocol_major()) + "." +
                      std::to_string(h.protocol_minor()) + ", '" + identity_.name + "' speaks " +
                      std::to_string(kProtocolMajor) + "." + std::to_string(kProtocolMinor) +
                      ": incompatible major version");
  }
  if (h.role() != identity_.expected_peer) {
    return refuse(v1::Refusal::WRONG_ROLE, "peer " + describe_peer(h) + " is a " +
                                               role_name(h.role()) + ", '" + identity_.name +
                                               "' expects a " + role_name(identity_.expected_peer));
  }
  const BindResult bound = binder_ ? binder_(h, *this) : BindResult{stream_, {}, {}};
  if (!bound.stream) return refuse(bound.reason, bound.detail, bound.repeated);
  stream_ = bound.stream;
  PeerStream& stream = *stream_;
  if (h.session_id() != stream.peer_session_id_) {
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
  const Clock::time_point now = this->now();
  // The peer's ack counts only if it refers to this process's stream.
  if (h.resume_session_id() == identity_.session_id && envelope.ack() != 0) {
    stream.sender_.on_ack(envelope.ack(), now);
  }
  stream.sender_.on_link_up();
  stream.sender_.rewind();
  stream.peer_hello_ = h;
  peer_hello_ok_ = true;
  if (hello_sent_) become_ready();
  if (!closed_) link_->wake_writer();  // our hello (if not out yet), then what waited for the link
}

void SessionLink::refuse(v1::Refusal::Reason reason, const std::string& detail, bool repeated) {
  ++counters_.refusals_sent;
  const bool same = same_as_last_refusal(detail);
  spdlog::log(repeated || same ? spdlog::level::debug : spdlog::level::err,
              "backbone: refusing {}: {}", link_->peer_name(), detail);
  scratch_.Clear();
  v1::Refusal& r = *scratch_.mutable_refusal();
  r.set_reason(reason);
  r.set_detail(detail);
  refusal_.clear();
  append_message(refusal_, scratch_);
  link_->wake_writer();
}

void SessionLink::protocol_error(const std::string& why) {
  ++counters_.protocol_errors;
  spdlog::error("backbone: protocol error on {}: {}; closing the link", link_->peer_name(), why);
  link_->close();
}

void SessionLink::on_closed() {
  if (closed_) return;
  closed_ = true;
  auto self = shared_from_this();  // the stream may hold the last reference
  watchdog_.cancel();
  if (ready_ && stream_ && stream_->link_.get() == this) {
    stream_->link_.reset();
    stream_->sender_.on_link_down();
    // What waits here behind a gap is still unacknowledged at the peer, which resends it on the
    // next link, and may have withdrawn part of it meanwhile (SDO requests its master was told
    // had failed): only the peer's resent version may be delivered.
    stream_->receiver_.reset(stream_->receiver_.expected());
    spdlog::info("backbone: link to {} over {} closed ({})", describe_peer(stream_->peer_hello_),
                 link_->peer_name(), link_->counters().close_reason.message());
    if (stream_->handlers_.on_down) stream_->handlers_.on_down();
  }
}

// Resend requests and single retransmissions are throttled to this, well below the retransmit
// timeout, so a lost retransmission is asked for again long before the timeout falls back.
std::chrono::steady_clock::duration SessionLink::resend_interval() const {
  return std::max<std::chrono::steady_clock::duration>(options_.retransmit_timeout / 4,
                                                       std::chrono::milliseconds{1});
}

std::chrono::steady_clock::duration SessionLink::watchdog_tick() const {
  const auto shortest =
      std::min({options_.keepalive_interval, options_.dead_after, options_.retransmit_timeout});
  return std::clamp(shortest / 4, std::chrono::milliseconds{5}, std::chrono::milliseconds{250});
}

void SessionLink::arm_watchdog() {
  // One deadline per link covers dead-link detection, keepalives and retransmission.
  watchdog_.expires_after(watchdog_tick());
  watchdog_.async_wait([weak = weak_from_this()](boost::system::error_code ec) {
    auto self = weak.lock();
    if (!ec && self) self->on_watchdog();
  });
}

void SessionLink::on_watchdog() {
  if (closed_ || !link_->is_open()) return;  // closing already (its handler may come later)
  const Clock::time_point now = this->now();
  if (now - last_rx_ <= options_.dead_after && now - last_run_ > peer_patience()) {
    return close_stale("this side did not run for longer than the peer waits", now);
  }
  last_run_ = now;
  // Not reading (PeerStream::pause_input): the silence is ours, and so are the missing acks.
  const bool deaf = link_->reading_paused();
  if (deaf) last_rx_ = now;
  if (now - last_rx_ > options_.dead_after) {
    ++counters_.dead_links;
    spdlog::warn("backbone: nothing from {} for {} ms: link dead, closing it", link_->peer_name(),
                 std::chrono::duration_cast<std::chrono::milliseconds>(now - last_rx_).count());
    link_->close();
    return;
  }
  if (initiator_ && !ready_ && hello_sent_ && now - last_tx_ >= options_.keepalive_interval) {
    hello_sent_ = false;  // no answer yet: the hello may have been lost on a noisy line
    link_->wake_writer();
  }
  if (ready_) {
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
    if (wake) link_->wake_writer();
  }
  arm_watchdog();
}

}  // namespace canbridge::backbone
