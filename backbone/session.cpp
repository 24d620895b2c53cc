#include "backbone/session.hpp"

#include <spdlog/spdlog.h>

#include <random>

namespace canbridge::backbone {

namespace {
// The same alias as session_core.cpp's, in the same kind of scope: in a unity batch holding both
// files a namespace-scope alias here shadowed that one (clang's -Wshadow).
using Clock = std::chrono::steady_clock;
}  // namespace

std::uint64_t random_session_id() {
  std::random_device device;
  std::uint64_t id = 0;
  while (id == 0) id = (std::uint64_t{device()} << 32) ^ device();
  return id;
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
      clock_(options.clock),
      binder_(std::move(binder)),
      core_(identity, options, preset, counters, log ? *log : own_log_, *this,
            SessionCore::LinkFacts{link_->peer_name(), link_->crc_framed(),
                                   link_->authenticated_peer()}),
      timer_(link_->executor()) {}

SessionLink::~SessionLink() = default;

void SessionLink::start() {
  // The core first: a link may run its writer at once, and the core measures every silence,
  // and whether this side ran, from its start.
  core_.start(now());
  std::weak_ptr<SessionLink> weak = weak_from_this();
  link_->start(
      [weak](std::span<const std::uint8_t> bytes) {
        if (auto self = weak.lock()) self->core_.on_message(bytes, self->input_now());
      },
      [weak](std::string& out) {
        if (auto self = weak.lock()) self->core_.fill(out, self->now());
      },
      [weak](std::error_code) {
        if (auto self = weak.lock()) self->on_closed();
      });
  arm_timer();
}

void SessionLink::close() {
  link_->close();
}

Clock::time_point SessionLink::now() const {
  return clock_ ? clock_() : Clock::now();
}

Clock::time_point SessionLink::input_now() {
  const std::uint64_t batch = link_->input_batches();
  if (batch != input_batch_) {  // every delivery starts a batch, so the first message reads it
    input_batch_ = batch;
    input_time_ = now();
  }
  return input_time_;
}

void SessionLink::on_closed() {
  if (core_.closed()) return;
  auto self = shared_from_this();  // the stream may hold the last reference
  timer_.cancel();
  PeerStream* stream = core_.stream();
  const bool carried = core_.ready() && stream && stream->link_.get() == this;
  if (carried) stream->link_.reset();
  core_.on_link_closed(carried, link_->counters().close_reason.message());
}

// One timer per link, at the core's next deadline (measured on the session's clock; without an
// injected one that is the timer's own, and arming it reads no clock).
void SessionLink::arm_timer() {
  if (clock_) {
    timer_.expires_after(std::max(core_.next_deadline() - now(), Clock::duration::zero()));
  } else {
    timer_.expires_at(core_.next_deadline());
  }
  timer_.async_wait([weak = weak_from_this()](boost::system::error_code ec) {
    auto self = weak.lock();
    if (!ec && self) self->on_timer();
  });
}

void SessionLink::on_timer() {
  if (core_.closed() || !link_->is_open()) return;  // closing already (its handler may come later)
  const std::uint64_t rx_bytes = link_->counters().rx_bytes;
  const bool bytes_arrived = rx_bytes != rx_bytes_at_tick_;
  rx_bytes_at_tick_ = rx_bytes;
  core_.on_tick(now(), link_->reading_paused(), bytes_arrived);
  if (link_->is_open()) arm_timer();
}

void SessionLink::wake_writer() {
  link_->wake_writer();
}

void SessionLink::close_link(std::error_code reason) {
  link_->close(reason);
}

void SessionLink::pause_reading(bool paused) {
  link_->pause_reading(paused);
}

BindResult SessionLink::bind(const v1::Hello& peer) {
  return binder_ ? binder_(peer, *this) : BindResult{core_.stream(), {}, {}};
}

void SessionLink::carry(PeerStream& stream) {
  if (stream.link_ && stream.link_.get() != this) stream.link_->close();  // stale link
  stream.link_ = shared_from_this();
}

}  // namespace canbridge::backbone
