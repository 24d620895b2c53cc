// One established TCP connection carrying delimited messages both ways: a reader that hands each
// complete message to the user and a pull-model writer that batches whatever the user has queued.
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <system_error>
#include <vector>

#include "backbone/delimited_codec.hpp"

namespace canbridge::backbone {

struct LinkOptions {
  std::size_t max_message_size = kDefaultMaxMessageSize;
  std::size_t read_buffer_size = 64 * 1024;
  // SO_SNDBUF/SO_RCVBUF in bytes; 0 keeps the kernel's autotuning. A fixed, moderate size bounds
  // how much data can queue in the kernel, so a slow link pushes back on the source (which can
  // then coalesce or drop) instead of hiding seconds of latency in socket buffers.
  int socket_buffer_size = 256 * 1024;
};

struct LinkCounters {
  std::uint64_t rx_messages = 0;
  std::uint64_t rx_bytes = 0;
  std::uint64_t tx_writes = 0;  // completed writes; each carries one or more messages
  std::uint64_t tx_bytes = 0;
  std::uint64_t malformed = 0;   // malformed length prefixes (the link was dropped)
  std::uint64_t oversize = 0;    // announced lengths above max_message_size (the link was dropped)
  std::error_code close_reason;  // empty while the link is open
};

// Not thread-safe: every member must be called on the socket's executor (one io_context thread).
class MessageLink : public std::enable_shared_from_this<MessageLink> {
 public:
  using MessageHandler = std::function<void(std::span<const std::uint8_t> message)>;
  // Appends zero or more complete delimited messages (append_message) to `out`, which is empty on
  // entry. Called when the writer is idle and woken, and again after every write completes.
  using Source = std::function<void(std::string& out)>;
  using ClosedHandler = std::function<void(std::error_code reason)>;

  // Takes over a connected socket; sets TCP_NODELAY and the socket buffer sizes.
  static std::shared_ptr<MessageLink> create(boost::asio::ip::tcp::socket socket,
                                             LinkOptions options = {});
  ~MessageLink();
  MessageLink(const MessageLink&) = delete;
  MessageLink& operator=(const MessageLink&) = delete;

  // Starts the reader and writer loops; call once. on_message gets every message in order (the
  // view is valid only during the call). The writer calls source once right away. on_closed is
  // called exactly once, after both loops have stopped, so no handler runs after it; the link
  // then drops all three handlers (they may safely capture the link's shared_ptr).
  void start(MessageHandler on_message, Source source, ClosedHandler on_closed);

  // Tells an idle writer that the source has something. Cheap; call it as often as you like.
  // When the writer is idle this calls the source and sends right away (one non-blocking send);
  // further wakes coalesce until that write has "completed" on a later turn of the loop.
  void wake_writer();

  // Ends the link (reason errc::closed unless it already ended); both loops stop promptly and
  // unsent data is discarded. Idempotent; safe from inside any handler.
  void close();

  // Completes with the close reason once the link has ended and on_closed has run (at once if it
  // already has). Completes with std::errc::operation_canceled if the caller is cancelled.
  boost::asio::awaitable<std::error_code> async_wait_closed();

  bool started() const noexcept { return started_; }
  bool is_open() const noexcept { return !closing_; }
  LinkCounters counters() const { return counters_; }
  const boost::asio::ip::tcp::endpoint& remote_endpoint() const noexcept { return remote_; }
  // For socket options and diagnostics only; never read or write through it.
  boost::asio::ip::tcp::socket::native_handle_type native_handle() {
    return socket_.native_handle();
  }

 private:
  MessageLink(boost::asio::ip::tcp::socket socket, LinkOptions options);

  boost::asio::awaitable<void> read_loop();
  boost::asio::awaitable<void> write_loop();
  void loop_done(std::exception_ptr error);
  void end(std::error_code reason);
  void finish();
  void report_decode_error(std::error_code error);
  void report_handler_error(std::exception_ptr error);
  bool write_inline();
  void write_done();

  boost::asio::ip::tcp::socket socket_;
  LinkOptions options_;
  boost::asio::ip::tcp::endpoint remote_;
  DelimitedDecoder decoder_;
  std::vector<std::uint8_t> read_buffer_;
  std::string write_buffer_;
  std::size_t write_offset_ = 0;      // bytes of write_buffer_ already sent by an inline send
  boost::asio::steady_timer wake_;    // condition variable for the idle writer
  boost::asio::steady_timer closed_;  // condition variable for async_wait_closed()
  MessageHandler on_message_;
  Source source_;
  ClosedHandler on_closed_;
  LinkCounters counters_;
  int loops_running_ = 0;
  bool started_ = false;
  bool closing_ = false;          // end() ran: loops are stopping
  bool finished_ = false;         // loops stopped and on_closed ran
  bool writer_sleeping_ = false;  // the writer waits on wake_
  bool wake_requested_ = false;   // wake_writer() since the source was last called
};

}  // namespace canbridge::backbone
