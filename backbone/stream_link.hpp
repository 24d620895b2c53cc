// The MessageLink over a byte stream (a TCP connection, plain or TLS, or a serial line): a reader
// loop that splits the stream into messages and a writer loop that batches whatever the source
// has queued, sending inline from wake_writer() when idle (plain TCP and serial). TCP frames
// messages by length prefix; a serial line, which can corrupt, lose or cut bytes, frames them with
// COBS + CRC-32C and resynchronises after damage.
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/serial_port.hpp>
#include <boost/asio/ssl/stream.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <system_error>
#include <variant>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/message_link.hpp"
#include "backbone/serial_framing.hpp"

namespace canbridge::backbone {

// How messages are delimited on the byte stream.
enum class LinkFraming {
  automatic,    // length prefix on TCP, COBS + CRC-32C on serial lines
  delimited,    // varint length prefix: for transports that never corrupt bytes
  cobs_crc32c,  // COBS + CRC-32C per message: for anything that can corrupt, lose or cut bytes
};

// Which undecodable input the links of one side (a server's accepted links) have warned about
// already: a flood of hostile connections, each sending garbage, then costs counters, not a log
// line per connection.
struct StreamLinkWarnings {
  bool malformed = false;
  bool oversize = false;
};

struct StreamLinkOptions {
  LinkFraming framing = LinkFraming::automatic;
  std::size_t max_message_size = kDefaultMaxMessageSize;
  std::size_t read_buffer_size = 64 * 1024;
  // SO_SNDBUF/SO_RCVBUF in bytes; 0 keeps the kernel's autotuning. A fixed, moderate size bounds
  // how much data can queue in the kernel, so a slow link pushes back on the source (which can
  // then coalesce or drop) instead of hiding seconds of latency in socket buffers.
  int socket_buffer_size = 256 * 1024;
  // Shared by the links of one side (TcpServer sets one for all it accepts); empty: per link.
  std::shared_ptr<StreamLinkWarnings> warnings;
  // A serial line's rate in bytes per second (baud / 10 for 8N1); 0: not paced. A paced writer
  // keeps at most `line_lead` of line time written ahead of the line: what the driver, a UART's
  // FIFO or a modem would otherwise buffer waits in the session's queues instead, where it
  // batches (fewer bytes per frame), conflates by its real age and lets urgent frames go first.
  std::size_t line_bytes_per_second = 0;
  std::chrono::microseconds line_lead{20'000};
};

// Not thread-safe: every member must be called on the stream's executor (one io_context thread).
class StreamLink final : public MessageLink, public std::enable_shared_from_this<StreamLink> {
 public:
  // Takes over a connected socket; sets TCP_NODELAY and the socket buffer sizes.
  static std::shared_ptr<StreamLink> create(boost::asio::ip::tcp::socket socket,
                                            StreamLinkOptions options = {});
  // Takes over a TLS stream whose handshake is done (backbone/tls_upgrade.hpp); sets TCP_NODELAY
  // and the buffer sizes on its socket. `authenticated_peer` is the identity the handshake proved.
  static std::shared_ptr<StreamLink> create(
      boost::asio::ssl::stream<boost::asio::ip::tcp::socket> stream, std::string authenticated_peer,
      StreamLinkOptions options = {});
  // Takes over an open, configured serial port (or pty); `name` is the device, for logs.
  static std::shared_ptr<StreamLink> create(boost::asio::serial_port port, std::string name,
                                            StreamLinkOptions options = {});
  ~StreamLink() override;

  // Starts the reader and writer loops; on_closed comes after both loops have stopped.
  void start(MessageHandler on_message, Source source, ClosedHandler on_closed) override;

  // Tells an idle writer that the source has something. Cheap; call it as often as you like.
  // When the writer is idle this calls the source and sends right away (one non-blocking send);
  // further wakes coalesce until that write has "completed" on a later turn of the loop. From
  // inside on_message the send waits until the current input batch has been handed over.
  void wake_writer() override;

  // While paused the socket is not read: the peer's writes back up in the kernel buffers.
  void pause_reading(bool paused) override;
  bool reading_paused() const noexcept override { return reading_paused_; }

  using MessageLink::close;
  void close(std::error_code reason) override;

  boost::asio::awaitable<std::error_code> async_wait_closed() override;

  boost::asio::any_io_executor executor() override { return wake_.get_executor(); }
  bool started() const noexcept override { return started_; }
  bool is_open() const noexcept override { return !closing_; }
  LinkCounters counters() const override { return counters_; }
  // "address:port" or the serial device.
  const std::string& peer_name() const noexcept override { return peer_name_; }
  // COBS + CRC-32C framed: serial lines, or TCP across a lossy path (LinkFraming::cobs_crc32c).
  bool crc_framed() const noexcept override { return crc_framed_; }
  std::uint64_t input_batches() const noexcept override { return input_batches_; }
  // Held while paused, or waiting in the socket or serial driver (one ioctl).
  bool input_waiting() override;
  // The identity a TLS handshake proved; empty on plain TCP and serial links.
  const std::string& authenticated_peer() const noexcept override { return authenticated_peer_; }

  // The TCP peer (an empty endpoint on a serial link).
  const boost::asio::ip::tcp::endpoint& remote_endpoint() const noexcept { return remote_; }
  bool paced() const noexcept { return options_.line_bytes_per_second > 0; }
  // Paced links: accounts `bytes` just written and waits while the line is more than line_lead
  // behind them.
  boost::asio::awaitable<void> pace(std::size_t bytes);
  bool is_serial() const noexcept {
    return std::holds_alternative<boost::asio::serial_port>(stream_);
  }
  bool is_tls() const noexcept { return std::holds_alternative<TlsStream>(stream_); }
  // For socket options and diagnostics only; never read or write through it.
  int native_handle();

 private:
  using TlsStream = boost::asio::ssl::stream<boost::asio::ip::tcp::socket>;
  using Stream = std::variant<boost::asio::ip::tcp::socket, boost::asio::serial_port, TlsStream>;
  StreamLink(Stream stream, std::string peer_name, StreamLinkOptions options);

  // Turns the delimited messages the source appended to staging_ into serial frames.
  void frame_staged_for_serial();
  bool fill_write_buffer();
  // Hands the messages in unread_ to on_message until it is empty, paused or closing, in batches
  // of about kInputSliceBytes; what they queue for the writer goes out after each batch.
  void deliver();
  // The writer was woken while idle: send now (inline), or resume it.
  void start_write();
  // The end of an input batch (`more_input`: of a slice, the read goes on): send what it queued.
  void write_after_batch(bool more_input);

  boost::asio::awaitable<void> read_loop();
  boost::asio::awaitable<void> write_loop();
  // Both loops end here (coro::spawn_owned): `failure` is what a handler threw, else empty.
  void loop_done(const std::string& failure);
  void end(std::error_code reason);
  void finish();
  void report_decode_error(std::error_code error);
  void report_handler_error(const std::string& what);
  bool write_inline();
  void write_done();
  // The TCP socket under a plain or TLS stream; null on a serial link.
  boost::asio::ip::tcp::socket* tcp_socket() noexcept;
  // Why a read ended, in the link's terms.
  std::error_code read_end_reason(const boost::system::error_code& ec) const;

  Stream stream_;
  StreamLinkOptions options_;
  boost::asio::ip::tcp::endpoint remote_;
  std::string peer_name_;
  std::string authenticated_peer_;
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
  boost::asio::steady_timer pace_;    // a paced writer waits for the line to drain
  // Paced links: when the line will have sent every byte written so far (a model of the line).
  std::chrono::steady_clock::time_point line_drained_at_{};
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
  bool delivering_ = false;       // inside deliver(): a wake waits for the end of the batch
  bool writer_resuming_ = false;  // resumed after an inline send, and has not run yet
  std::uint64_t input_batches_ = 0;
  bool reading_paused_ = false;
};

}  // namespace canbridge::backbone
