#include "backbone/memory_link.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <exception>

#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;

MemoryLinkPair make_memory_link_pair(asio::any_io_executor executor, MemoryLinkOptions options) {
  MemoryLinkPair pair;
  pair.a =
      std::make_shared<MemoryLink>(MemoryLink::Private{}, executor, options.name + "/b", options);
  pair.b =
      std::make_shared<MemoryLink>(MemoryLink::Private{}, executor, options.name + "/a", options);
  pair.a->peer_ = pair.b;
  pair.b->peer_ = pair.a;
  return pair;
}

MemoryLink::MemoryLink(Private, asio::any_io_executor executor, std::string peer_name,
                       const MemoryLinkOptions& options)
    : executor_(std::move(executor)),
      options_(options),
      peer_name_(std::move(peer_name)),
      decoder_(options.max_message_size),
      closed_(executor_, asio::steady_timer::time_point::max()) {}

MemoryLink::~MemoryLink() {
  // Dropped while open: the other end sees the link go, as it would see a process die.
  if (!closing_ && !peer_gone_) {
    if (auto far = peer_.lock()) far->peer_ended();
  }
}

void MemoryLink::start(MessageHandler on_message, Source source, ClosedHandler on_closed) {
  if (started_) {
    spdlog::error("backbone: MemoryLink::start called twice on {}", peer_name_);
    return;
  }
  started_ = true;
  if (finished_) {
    // Closed before it was started: still honour "on_closed exactly once", but not reentrantly.
    if (on_closed) {
      asio::post(executor_, [handler = std::move(on_closed), reason = counters_.close_reason] {
        handler(reason);
      });
    }
    return;
  }
  on_message_ = std::move(on_message);
  source_ = std::move(source);
  on_closed_ = std::move(on_closed);
  wake_requested_ = true;
  schedule_write();  // the writer asks the source once right away
  if (unread_bytes() > 0 || peer_gone_) schedule_delivery();
}

void MemoryLink::wake_writer() {
  wake_requested_ = true;
  if (started_ && !closing_ && !writer_blocked_) schedule_write();
}

void MemoryLink::pause_reading(bool paused) {
  if (reading_paused_ == paused) return;
  reading_paused_ = paused;
  if (!paused) schedule_delivery();
}

void MemoryLink::close(std::error_code reason) {
  end(reason);
}

asio::awaitable<std::error_code> MemoryLink::async_wait_closed() {
  auto self = shared_from_this();  // the link outlives the wait
  while (!finished_) {
    co_await closed_.async_wait(asio::as_tuple(asio::use_awaitable));
    // The timer is a condition variable: cancel() means "finished". A cancellation requested by
    // our caller must still end the wait.
    auto state = co_await asio::this_coro::cancellation_state;
    if (state.cancelled() != asio::cancellation_type::none && !finished_) {
      co_return std::make_error_code(std::errc::operation_canceled);
    }
  }
  co_return counters_.close_reason;
}

void MemoryLink::schedule_write() {
  if (write_scheduled_ || !started_ || closing_) return;
  write_scheduled_ = true;
  asio::post(executor_, [self = shared_from_this()] { self->write_turn(); });
}

// One write: what the source has, as one batch, if the other end has room for it.
void MemoryLink::write_turn() {
  write_scheduled_ = false;
  if (closing_) return;
  auto far = peer_gone_ ? nullptr : peer_.lock();
  if (far && far->unread_bytes() >= options_.capacity_bytes) {
    writer_blocked_ = true;  // the other end's deliver_turn resumes us once it has read
    return;
  }
  wake_requested_ = false;
  write_buffer_.clear();
  try {
    if (source_) source_(write_buffer_);
  } catch (...) {
    return handler_failed("source");
  }
  if (closing_) return;
  if (write_buffer_.empty()) {
    if (wake_requested_) schedule_write();  // woken from inside the source: ask again
    return;
  }
  if (far) {
    far->take(write_buffer_);
  } else if (wrote_after_peer_gone_) {
    return end(std::make_error_code(std::errc::connection_reset));
  } else {
    wrote_after_peer_gone_ = true;  // taken, like bytes the kernel accepts before the reset
  }
  ++counters_.tx_writes;
  counters_.tx_bytes += write_buffer_.size();
  schedule_write();  // the write completed: ask the source again, as the stream writer does
}

void MemoryLink::take(const std::string& batch) {
  if (closing_) return;
  if (inbox_offset_ > 0 && inbox_offset_ >= inbox_.size() / 2) {  // paused part-way: compact
    inbox_.erase(0, inbox_offset_);
    inbox_offset_ = 0;
  }
  inbox_.append(batch);
  schedule_delivery();
}

void MemoryLink::peer_ended() {
  peer_gone_ = true;
  if (writer_blocked_) {  // waited for room that will never come: let it find the end
    writer_blocked_ = false;
    schedule_write();
  }
  schedule_delivery();
}

void MemoryLink::schedule_delivery() {
  if (delivery_scheduled_ || !started_ || closing_ || reading_paused_) return;
  delivery_scheduled_ = true;
  asio::post(executor_, [self = shared_from_this()] { self->deliver_turn(); });
}

// Hands the unread messages to on_message one at a time, so that a handler that pauses or closes
// stops delivery at once.
void MemoryLink::deliver_turn() {
  delivery_scheduled_ = false;
  ++input_batches_;
  while (!closing_ && !reading_paused_ && unread_bytes() > 0) {
    std::span<const std::uint8_t> rest(
        reinterpret_cast<const std::uint8_t*>(inbox_.data()) + inbox_offset_, unread_bytes());
    const std::size_t before = rest.size();
    const auto message = decoder_.next(rest);
    inbox_offset_ += before - rest.size();
    counters_.rx_bytes += before - rest.size();
    if (!message) break;  // a decode error, or a partial message (a source that broke the rules)
    ++counters_.rx_messages;
    try {
      if (on_message_) on_message_(*message);
    } catch (...) {
      return handler_failed("message handler");
    }
  }
  if (closing_) return;
  if (const std::error_code error = decoder_.error()) {
    ++(error == errc::malformed_length ? counters_.malformed : counters_.oversize);
    spdlog::warn("backbone: dropping {} after {}", peer_name_, error.message());
    return end(error);
  }
  if (unread_bytes() == 0) {
    inbox_.clear();
    inbox_offset_ = 0;
  }
  auto far = peer_gone_ ? nullptr : peer_.lock();
  if (far && far->writer_blocked_ && unread_bytes() < options_.capacity_bytes) {
    far->writer_blocked_ = false;
    far->schedule_write();
  }
  if (!reading_paused_ && unread_bytes() == 0 && peer_gone_)
    end(make_error_code(errc::peer_closed));
}

void MemoryLink::handler_failed(const char* which) {
  spdlog::error("backbone: {} on link {} threw: {}", which, peer_name_,
                coro::describe_exception(std::current_exception()));
  end(make_error_code(errc::handler_failed));
}

void MemoryLink::end(std::error_code reason) {
  if (closing_) return;
  closing_ = true;
  counters_.close_reason = reason;
  spdlog::debug("backbone: link {} ends: {}", peer_name_, reason.message());
  writer_blocked_ = false;
  if (!peer_gone_) {
    if (auto far = peer_.lock()) far->peer_ended();
  }
  peer_.reset();
  if (!started_) {
    finish();  // no handlers yet: start() posts on_closed
    return;
  }
  // Never from inside close(): a handler may be running right now (and the inbox holds the view
  // it was given), so release everything on a later turn.
  asio::post(executor_, [self = shared_from_this()] { self->finish(); });
}

void MemoryLink::finish() {
  if (finished_) return;
  finished_ = true;
  on_message_ = nullptr;  // breaks reference cycles through handlers that captured the link
  source_ = nullptr;
  auto on_closed = std::move(on_closed_);
  on_closed_ = nullptr;
  std::string().swap(inbox_);
  inbox_offset_ = 0;
  std::string().swap(write_buffer_);
  closed_.cancel();
  if (on_closed) on_closed(counters_.close_reason);
}

}  // namespace canbridge::backbone
