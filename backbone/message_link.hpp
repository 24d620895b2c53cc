// The one interface every backbone link offers to a session (TCP or serial stream, in-memory
// pair, fakes): an established connection carrying whole messages both ways, with a reader that
// hands each message to the user and a pull-model writer that batches whatever the user queued.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <system_error>

#include "backbone/delimited_codec.hpp"
#include "backbone/serial_framing.hpp"

namespace canbridge::backbone {

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

// Not thread-safe: every member must be called on executor() (one io_context thread).
// Implementations: StreamLink (backbone/stream_link.hpp: a TCP socket or a serial port) and the
// in-memory pair (backbone/memory_link.hpp).
class MessageLink {
 public:
  using MessageHandler = std::function<void(std::span<const std::uint8_t> message)>;
  // Appends zero or more complete delimited messages (append_message) to `out`, which is empty on
  // entry. Called when the writer is idle and woken, and again after every write completes.
  using Source = std::function<void(std::string& out)>;
  using ClosedHandler = std::function<void(std::error_code reason)>;

  virtual ~MessageLink() = default;
  MessageLink(const MessageLink&) = delete;
  MessageLink& operator=(const MessageLink&) = delete;

  // Starts the reader and writer; call once. on_message gets every message in order (the view is
  // valid only during the call). The writer calls source once right away. on_closed is called
  // exactly once, never from inside close(), after which no handler runs; the link then drops all
  // three handlers (they may safely capture the link's shared_ptr).
  virtual void start(MessageHandler on_message, Source source, ClosedHandler on_closed) = 0;

  // Tells an idle writer that the source has something. Cheap; call it as often as you like:
  // wakes coalesce until the writer next calls the source. A wake from inside on_message is
  // served once the batch being delivered has been handed over: whatever all its messages
  // queued (acks, answers) then goes out in one write.
  virtual void wake_writer() = 0;

  // How many batches of input the reader has handed to on_message so far. A batch is what one
  // read of the transport brought in (a large read is handed over in slices, so that what its
  // messages queue is written, and time is looked at, while the rest is still being handled):
  // its messages arrived together, so a user may read its clock once per batch, not per message.
  virtual std::uint64_t input_batches() const noexcept = 0;

  // Bytes have arrived that the reader has not handed over yet (waiting in the transport, or read
  // and held while paused): the peer did send them, though this side has not run to read them.
  // May cost a syscall; for rare decisions (is the link dead?), not per message.
  virtual bool input_waiting() = 0;

  // While paused, no message reaches on_message and the transport is not read, so the peer's
  // writes back up into its own buffers: for a receiver that cannot take more for a while.
  // Messages already read wait and come first on resume. The writer goes on as before.
  virtual void pause_reading(bool paused) = 0;
  virtual bool reading_paused() const noexcept = 0;

  // Ends the link (reason errc::closed unless it already ended); reader and writer stop promptly
  // and unsent data is discarded. Idempotent; safe from inside any handler.
  void close() { close(make_error_code(errc::closed)); }
  // The same, with the reason the link's client will see (e.g. errc::refused_by_peer).
  virtual void close(std::error_code reason) = 0;

  // Completes with the close reason once the link has ended and on_closed has run (at once if it
  // already has). Completes with std::errc::operation_canceled if the caller is cancelled.
  virtual boost::asio::awaitable<std::error_code> async_wait_closed() = 0;

  virtual boost::asio::any_io_executor executor() = 0;
  virtual bool started() const noexcept = 0;
  virtual bool is_open() const noexcept = 0;
  virtual LinkCounters counters() const = 0;
  // Who is at the other end, for logs ("address:port", a serial device, a memory pair's name).
  virtual const std::string& peer_name() const noexcept = 0;
  // Messages cross a path that can corrupt, lose or cut bytes (a serial line, or TCP across a
  // lossy path), COBS + CRC-32C framed: the session then tolerates what such a line does.
  virtual bool crc_framed() const noexcept = 0;
  // The identity the transport proved for the peer (a TLS PSK identity's name or a certificate's
  // name), empty when the transport proved nothing (plain TCP, a serial line: there the session
  // authenticates, see SessionLink::authenticated_peer).
  virtual const std::string& authenticated_peer() const noexcept {
    static const std::string none;
    return none;
  }

 protected:
  MessageLink() = default;
};

}  // namespace canbridge::backbone
