#include "backbone/stream_link.hpp"

#include <fcntl.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <spdlog/spdlog.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/error.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <cerrno>
#include <exception>

#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
using asio::ip::tcp;

namespace {

using coro::kNoError;

// Past this, the write buffer is released after use so one burst does not pin memory forever.
constexpr std::size_t kRetainedWriteCapacity = std::size_t{1} << 20;

// One input batch: a full 64 KiB read of small messages can take its handlers a long time (each
// frame written to a bus); in slices of this size the session looks at its clock (keepalives)
// and what the messages queued (acks) goes out while the rest of the read is handled.
constexpr std::size_t kInputSliceBytes = 4 * 1024;

std::string describe(const tcp::endpoint& endpoint) {
  return endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
}

}  // namespace

std::shared_ptr<StreamLink> StreamLink::create(tcp::socket socket, StreamLinkOptions options) {
  boost::system::error_code ec;
  const tcp::endpoint remote = socket.remote_endpoint(ec);
  auto link =
      std::shared_ptr<StreamLink>(new StreamLink(std::move(socket), describe(remote), options));
  link->remote_ = remote;
  return link;
}

std::shared_ptr<StreamLink> StreamLink::create(TlsStream stream, std::string authenticated_peer,
                                               StreamLinkOptions options) {
  boost::system::error_code ec;
  const tcp::endpoint remote = stream.lowest_layer().remote_endpoint(ec);
  auto link =
      std::shared_ptr<StreamLink>(new StreamLink(std::move(stream), describe(remote), options));
  link->remote_ = remote;
  link->authenticated_peer_ = std::move(authenticated_peer);
  return link;
}

std::shared_ptr<StreamLink> StreamLink::create(asio::serial_port port, std::string name,
                                               StreamLinkOptions options) {
  return std::shared_ptr<StreamLink>(new StreamLink(std::move(port), std::move(name), options));
}

StreamLink::StreamLink(Stream stream, std::string peer_name, StreamLinkOptions options)
    : stream_(std::move(stream)),
      options_(options),
      peer_name_(std::move(peer_name)),
      decoder_(options.max_message_size),
      deframer_(options.max_message_size),
      read_buffer_(std::max<std::size_t>(options.read_buffer_size, 1)),
      wake_(std::visit([](auto& s) { return s.get_executor(); }, stream_),
            asio::steady_timer::time_point::max()),
      closed_(wake_.get_executor(), asio::steady_timer::time_point::max()),
      resume_(wake_.get_executor(), asio::steady_timer::time_point::max()),
      pace_(wake_.get_executor()) {
  crc_framed_ = options.framing == LinkFraming::cobs_crc32c ||
                (options.framing == LinkFraming::automatic && is_serial());
  boost::system::error_code ec;
  if (auto* socket = tcp_socket()) {
    // Small, latency-bound messages: the writer already batches, so Nagle would only add delay.
    socket->set_option(tcp::no_delay(true), ec);
    if (ec) spdlog::warn("backbone: TCP_NODELAY on {} failed: {}", peer_name_, ec.message());
    if (options_.socket_buffer_size > 0) {
      socket->set_option(asio::socket_base::send_buffer_size(options_.socket_buffer_size), ec);
      socket->set_option(asio::socket_base::receive_buffer_size(options_.socket_buffer_size), ec);
    }
  } else {
    // The inline send writes the descriptor directly and must never block the loop.
    const int fd = native_handle();
    const int flags = ::fcntl(fd, F_GETFL);
    if (flags >= 0) ::fcntl(fd, F_SETFL, flags | O_NONBLOCK);
  }
}

int StreamLink::native_handle() {
  if (auto* socket = tcp_socket()) return socket->native_handle();
  return std::get<asio::serial_port>(stream_).native_handle();
}

tcp::socket* StreamLink::tcp_socket() noexcept {
  if (auto* socket = std::get_if<tcp::socket>(&stream_)) return socket;
  if (auto* tls = std::get_if<TlsStream>(&stream_)) return &tls->next_layer();
  return nullptr;
}

StreamLink::~StreamLink() = default;

void StreamLink::start(MessageHandler on_message, Source source, ClosedHandler on_closed) {
  if (started_) {
    spdlog::error("backbone: StreamLink::start called twice on {}", peer_name_);
    return;
  }
  started_ = true;
  if (finished_) {
    // Closed before it was started: still honour "on_closed exactly once", but not reentrantly.
    if (on_closed) {
      asio::post(wake_.get_executor(), [handler = std::move(on_closed),
                                        reason = counters_.close_reason] { handler(reason); });
    }
    return;
  }
  on_message_ = std::move(on_message);
  source_ = std::move(source);
  on_closed_ = std::move(on_closed);
  loops_running_ = 2;
  // Each loop holds the link alive until it ends, and reports why it ended.
  auto done = [self = shared_from_this()](const std::string& failure) { self->loop_done(failure); };
  coro::spawn_owned(wake_.get_executor(), read_loop(), done);
  coro::spawn_owned(wake_.get_executor(), write_loop(), done);
}

void StreamLink::wake_writer() {
  wake_requested_ = true;
  // Busy: it calls the source again once its write completes. Delivering: deliver() starts the
  // write once the batch is handed over, so that one write carries what all its messages queued.
  if (!writer_sleeping_ || delivering_) return;
  start_write();
}

void StreamLink::start_write() {
  writer_sleeping_ = false;  // one wake per sleep, however many wakes
  // TLS records are written by the stream's own async machinery only (a raw send would bypass
  // the encryption), so a TLS writer is always resumed to write.
  // A paced writer is always resumed too: it must know what it wrote and when, to keep the line
  // model, and a paced line carries few messages a second, so the inline send saves nothing.
  if (!is_tls() && !paced() && write_inline()) {
    writer_sleeping_ = !closing_;  // nothing to send after all: the writer sleeps on
    return;
  }
  writer_resuming_ = true;
  wake_.cancel();
}

// The end of an input batch: what its messages queued goes out now. Inside a long read the writer
// resumed after an earlier batch's inline send cannot run until the read is handled, so a batch
// may send inline behind it too, as long as that send left nothing for it to finish.
void StreamLink::write_after_batch(bool more_input) {
  if (!wake_requested_ || closing_) return;
  if (writer_sleeping_) return start_write();
  if (more_input && writer_resuming_ && write_buffer_.empty() && !is_tls() && !paced()) {
    write_inline();
  }
}

// The writer is asleep, so no write is in flight and the buffer is free: rather than resume the
// writer (a turn through the scheduler, then the send), ask the source and send right here. The
// writer is still resumed afterwards, as if this send were its own write completing: it finishes
// what the socket did not take and calls the source again, so that wakes until then coalesce
// into its next write exactly as they do behind any write. Returns true when the source had
// nothing (the writer may sleep on) or the link ended.
bool StreamLink::write_inline() {
  write_buffer_.clear();
  write_offset_ = 0;
  wake_requested_ = false;
  try {
    fill_write_buffer();
  } catch (...) {
    // What the coroutine writer would report through loop_done(); on_closed still comes once,
    // after both loops have stopped.
    report_handler_error(coro::describe_exception(std::current_exception()));
    end(make_error_code(errc::handler_failed));
    return true;
  }
  if (closing_) return true;
  // Woken from inside the source: let the writer ask again.
  if (write_buffer_.empty()) return !wake_requested_;
  const ssize_t sent = is_serial()
                           ? ::write(native_handle(), write_buffer_.data(), write_buffer_.size())
                           : ::send(native_handle(), write_buffer_.data(), write_buffer_.size(),
                                    MSG_DONTWAIT | MSG_NOSIGNAL);
  if (sent >= 0) {
    write_offset_ = static_cast<std::size_t>(sent);
    if (write_offset_ == write_buffer_.size()) write_done();
  } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
    end(std::error_code(errno, std::system_category()));
    return true;
  }
  return false;  // the writer sends the rest, if any, then calls the source again
}

// Asks the source for what is queued; on a serial link, re-frames it for the line. Returns
// whether there is anything to send.
bool StreamLink::fill_write_buffer() {
  if (!crc_framed_) {
    if (source_) source_(write_buffer_);
    return !write_buffer_.empty();
  }
  staging_.clear();
  if (source_) source_(staging_);
  if (!staging_.empty()) frame_staged_for_serial();
  return !write_buffer_.empty();
}

void StreamLink::frame_staged_for_serial() {
  if (!leading_delimiter_sent_) {
    // Ends whatever partial frame the receiver holds from before this link (noise, a cut), so
    // our first frame is not discarded with it.
    write_buffer_.push_back(static_cast<char>(kFrameDelimiter));
    leading_delimiter_sent_ = true;
  }
  DelimitedDecoder split(options_.max_message_size);
  std::span<const std::uint8_t> input(reinterpret_cast<const std::uint8_t*>(staging_.data()),
                                      staging_.size());
  while (auto message = split.next(input)) append_serial_frame(write_buffer_, *message);
}

// The whole write buffer has reached the socket.
void StreamLink::write_done() {
  ++counters_.tx_writes;
  counters_.tx_bytes += write_buffer_.size();
  if (write_buffer_.capacity() > kRetainedWriteCapacity) {
    std::string().swap(write_buffer_);
  } else {
    write_buffer_.clear();
  }
  write_offset_ = 0;
}

bool StreamLink::input_waiting() {
  if (!unread_.empty()) return true;
  if (closing_) return false;
  int waiting = 0;  // FIONREAD: the socket's receive queue; on a tty the same as TIOCINQ
  return ::ioctl(native_handle(), FIONREAD, &waiting) == 0 && waiting > 0;
}

void StreamLink::pause_reading(bool paused) {
  if (reading_paused_ == paused) return;
  reading_paused_ = paused;
  if (!paused) resume_.cancel();
}

void StreamLink::close(std::error_code reason) {
  end(reason);
}

asio::awaitable<std::error_code> StreamLink::async_wait_closed() {
  auto self = shared_from_this();  // the link outlives the wait
  while (!finished_) {
    co_await closed_.async_wait(kNoError);
    // The timer is a condition variable: cancel() means "finished". A cancellation requested by
    // our caller must still end the wait.
    auto state = co_await asio::this_coro::cancellation_state;
    if (state.cancelled() != asio::cancellation_type::none && !finished_) {
      co_return std::make_error_code(std::errc::operation_canceled);
    }
  }
  co_return counters_.close_reason;
}

asio::awaitable<void> StreamLink::read_loop() {
  while (!closing_) {
    if (reading_paused_) {
      co_await resume_.async_wait(kNoError);  // cancel(): resumed or closing
      continue;
    }
    if (!unread_.empty()) {  // paused in the middle of the last read
      deliver();
      if (!closing_ && !crc_framed_ && decoder_.error()) {
        report_decode_error(decoder_.error());
        end(decoder_.error());
      }
      continue;
    }
    auto [ec, n] = co_await std::visit(
        [this](auto& s) { return s.async_read_some(asio::buffer(read_buffer_), kNoError); },
        stream_);
    if (closing_) break;
    if (ec) {
      if (ec == asio::error::eof && !crc_framed_ && !decoder_.at_message_boundary()) {
        spdlog::debug("backbone: {} closed in the middle of a message", peer_name_);
      }
      end(read_end_reason(ec));
      break;
    }
    counters_.rx_bytes += n;
    unread_ = {read_buffer_.data(), n};
    deliver();
    if (!closing_ && !crc_framed_ && decoder_.error()) {
      report_decode_error(decoder_.error());
      end(decoder_.error());
    }
  }
}

// Pulls one message at a time so that a handler calling close() stops delivery at once.
void StreamLink::deliver() {
  ++input_batches_;
  std::size_t sliced = unread_.size();  // unread_ when the current batch began
  delivering_ = true;
  struct Done {
    StreamLink& link;
    ~Done() { link.delivering_ = false; }
  } done{*this};
  while (!closing_ && !reading_paused_) {
    auto message = crc_framed_ ? deframer_.next(unread_) : decoder_.next(unread_);
    if (!message) {
      unread_ = {};  // all taken (a partial message is kept by the decoder) or a decode error
      break;
    }
    ++counters_.rx_messages;
    if (on_message_) on_message_(*message);
    if (sliced - unread_.size() >= kInputSliceBytes && !unread_.empty()) {
      // The end of a batch: write what it queued, start the next.
      delivering_ = false;
      write_after_batch(true);
      delivering_ = true;
      sliced = unread_.size();
      ++input_batches_;
    }
  }
  delivering_ = false;
  write_after_batch(false);  // a resumed writer runs next and takes what the batch queued
  if (crc_framed_) counters_.deframer = deframer_.counters();
}

asio::awaitable<void> StreamLink::write_loop() {
  while (!closing_) {
    if (write_buffer_.empty()) {  // else: the rest of an inline send (write_inline) is pending
      write_offset_ = 0;
      wake_requested_ = false;
      fill_write_buffer();
      if (closing_) break;
      if (write_buffer_.empty()) {
        if (wake_requested_) continue;  // woken from inside the source: ask again
        writer_sleeping_ = true;
        wake_.expires_at(asio::steady_timer::time_point::max());
        co_await wake_.async_wait(kNoError);
        writer_sleeping_ = false;
        writer_resuming_ = false;
        continue;
      }
    }
    auto [ec, n] = co_await std::visit(
        [this](auto& s) {
          return asio::async_write(s, asio::buffer(write_buffer_) + write_offset_, kNoError);
        },
        stream_);
    if (closing_) break;
    if (ec) {
      end(ec);
      break;
    }
    write_done();
    if (paced()) {
      co_await pace(n);
      if (closing_) break;
    }
  }
}

asio::awaitable<void> StreamLink::pace(std::size_t bytes) {
  using namespace std::chrono;
  const auto now = steady_clock::now();
  const auto line_time = duration_cast<steady_clock::duration>(duration<double>(
      static_cast<double>(bytes) / static_cast<double>(options_.line_bytes_per_second)));
  line_drained_at_ = std::max(line_drained_at_, now) + line_time;
  const auto resume_at =
      line_drained_at_ - duration_cast<steady_clock::duration>(options_.line_lead);
  if (resume_at <= now) co_return;
  // Wakes meanwhile are remembered (wake_requested_): the next fill takes what they queued.
  pace_.expires_at(resume_at);
  co_await pace_.async_wait(kNoError);
}

std::error_code StreamLink::read_end_reason(const boost::system::error_code& ec) const {
  // A TLS peer closes without close_notify (as this end does): that is an ordinary close.
  if (ec == asio::error::eof || ec == asio::ssl::error::stream_truncated) {
    return make_error_code(errc::peer_closed);
  }
  // A TLS alert before any message: the peer's last check of the handshake refused us (a TLS 1.3
  // server checks the client's certificate after the client considers the handshake done).
  if (is_tls() && counters_.rx_messages == 0 && ec.category() == asio::error::get_ssl_category() &&
      ERR_GET_REASON(static_cast<unsigned long>(ec.value())) >= SSL_AD_REASON_OFFSET) {
    return make_error_code(errc::refused_by_peer);
  }
  return ec;
}

void StreamLink::report_handler_error(const std::string& what) {
  spdlog::error("backbone: handler on link {} threw: {}", peer_name_, what);
}

void StreamLink::report_decode_error(std::error_code error) {
  const bool malformed = error == errc::malformed_length;
  ++(malformed ? counters_.malformed : counters_.oversize);
  // Once per side (or link) and kind (counters keep the exact numbers); later ones go to debug.
  if (!options_.warnings) options_.warnings = std::make_shared<StreamLinkWarnings>();
  bool& warned = malformed ? options_.warnings->malformed : options_.warnings->oversize;
  if (!warned) {
    warned = true;
    spdlog::warn("backbone: dropping {} after {} (first occurrence; further ones are only counted)",
                 peer_name_, error.message());
  } else {
    spdlog::debug("backbone: dropping {} after {}", peer_name_, error.message());
  }
}

void StreamLink::end(std::error_code reason) {
  if (closing_) return;
  closing_ = true;
  counters_.close_reason = reason;
  spdlog::debug("backbone: link {} ends: {}", peer_name_, reason.message());
  boost::system::error_code ignored;
  // Aborts a pending read or write. A TLS link closes its socket without waiting for the
  // peer's close_notify: a dead peer would never send it.
  if (auto* socket = tcp_socket()) {
    socket->close(ignored);
  } else {
    std::get<asio::serial_port>(stream_).close(ignored);
  }
  writer_sleeping_ = false;
  wake_.cancel();
  resume_.cancel();
  pace_.cancel();
  if (loops_running_ == 0) finish();  // never started
}

void StreamLink::loop_done(const std::string& failure) {
  if (!failure.empty()) {
    report_handler_error(failure);
    end(make_error_code(errc::handler_failed));
  }
  if (--loops_running_ == 0) finish();
}

void StreamLink::finish() {
  if (finished_) return;
  finished_ = true;
  // Both loops are gone, so no handler is executing and dropping them is safe; this also breaks
  // reference cycles through handlers that captured the link.
  on_message_ = nullptr;
  source_ = nullptr;
  auto on_closed = std::move(on_closed_);
  on_closed_ = nullptr;
  closed_.cancel();
  if (on_closed) on_closed(counters_.close_reason);
}

}  // namespace canbridge::backbone
