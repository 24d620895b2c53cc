// One established byte link (a TCP connection or a serial line) carrying messages both ways: a
// reader that hands each complete message to the user and a pull-model writer that batches
// whatever the user has queued. TCP frames messages by length prefix; a serial line, which can
// corrupt, lose or cut bytes, frames them with COBS + CRC-32C and resynchronises after damage.
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/serial_port.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstdint>
#include <exception>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <system_error>
#include <variant>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/serial_framing.hpp"

namespace canbridge::backbone {

// How messages are delimited on the byte stream.
enum class LinkFraming {
  automatic,    // length prefix on TCP, COBS + CRC-32C on serial lines
  delimited,    // varint length prefix: for transports that never corrupt bytes
  cobs_crc32c,  // COBS + CRC-32C per message: for anything that can corrupt, lose or cut bytes
};

struct LinkOptions {
  LinkFraming framing = LinkFraming::automatic;
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
  std::uint64_t malformed = 0;  // malformed length prefixes (the link was dropped)
  std::uint64_t oversize = 0;   // announced lengths above max_message_size (the link was dropped)
  // COBS + CRC framing only: what the deframer discarded (corrupt, truncated, oversize frames).
  DeframerCounters deframer{};
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
  // Takes over an open, configured serial port (or pty); `name` is the device, for logs.
  static std::shared_ptr<MessageLink> create(boost::asio::serial_port port, std::string name,
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

  // While paused, no message reaches on_message and the transport is not read, so the peer's
  // writes back up into its own buffers: for a receiver that cannot take more for a while.
  // Messages already read wait and come first on resume. The writer goes on as before.
  void pause_reading(bool paused);
  bool reading_paused() const noexcept { return reading_paused_; }

  // Ends the link (reason errc::closed unless it already ended); both loops stop promptly and
  // unsent data is discarded. Idempotent; safe from inside any handler.
  void close();
  // The same, with the reason the link's client will see (e.g. errc::refused_by_peer).
  void close(std::error_code reason);

  // Completes with the close reason once the link has ended and on_closed has run (at once if it
  // already has). Completes with std::errc::operation_canceled if the caller is cancelled.
  boost::asio::awaitable<std::error_code> async_wait_closed();

  boost::asio::any_io_executor executor() { return wake_.get_executor(); }
  bool started() const noexcept { return started_; }
  bool is_open() const noexcept { return !closing_; }
  LinkCounters counters() const { return counters_; }
  // The TCP peer (an empty endpoint on a serial link).
  const boost::asio::ip::tcp::endpoint& remote_endpoint() const noexcept { return remote_; }
  // "address:port" or the serial device, for logs.
  const std::string& peer_name() const noexcept { return peer_name_; }
  bool is_serial() const noexcept {
    return std::holds_alternative<boost::asio::serial_port>(stream_);
  }
  // Messages are COBS + CRC-32C framed (serial lines, or TCP across a lossy path).
  bool crc_framed() const noexcept { return crc_framed_; }
  // For socket options and diagnostics only; never read or write through it.
  int native_handle();

 private:
  using Stream = std::variant<boost::asio::ip::tcp::socket, boost::asio::serial_port>;
  MessageLink(Stream stream, std::string peer_name, LinkOptions options);

  // Turns the delimited messages the source appended to staging_ into serial frames.
  void frame_staged_for_serial();
  bool fill_write_buffer();
  // Hands the messages in unread_ to on_message until it is empty, paused or closing.
  void deliver();

  boost::asio::awaitable<void> read_loop();
  boost::asio::awaitable<void> write_loop();
  void loop_done(std::exception_ptr error);
  void end(std::error_code reason);
  void finish();
  void report_decode_error(std::error_code error);
  void report_handler_error(std::exception_ptr error);
  bool write_inline();
  void write_done();

  Stream stream_;
  LinkOptions options_;
  boost::asio::ip::tcp::endpoint remote_;
  std::string peer_name_;
  DelimitedDecoder decoder_;  // TCP framing
  SerialDeframer deframer_;   // serial framing
  std::string staging_;       // serial: the source's delimited messages before framing
  bool crc_framed_ = false;
  bool leading_delimiter_sent_ = false;
  std::vector<std::uint8_t> read_buffer_;
  std::span<const std::uint8_t> unread_;  // read but not yet decoded (paused mid-buffer)
  std::string write_buffer_;
  std::size_t write_offset_ = 0;      // bytes of write_buffer_ already sent by an inline send
  boost::asio::steady_timer wake_;    // condition variable for the idle writer
  boost::asio::steady_timer closed_;  // condition variable for async_wait_closed()
  boost::asio::steady_timer resume_;  // condition variable for the paused reader
  MessageHandler on_message_;
  Source source_;
  ClosedHandler on_closed_;
  LinkCounters counters_;
  int loops_running_ = 0;
  bool started_ = false;
  bool warned_malformed_ = false;  // report_decode_error() said it once already
  bool warned_oversize_ = false;
  bool closing_ = false;          // end() ran: loops are stopping
  bool finished_ = false;         // loops stopped and on_closed ran
  bool writer_sleeping_ = false;  // the writer waits on wake_
  bool wake_requested_ = false;   // wake_writer() since the source was last called
  bool reading_paused_ = false;
};

}  // namespace canbridge::backbone
