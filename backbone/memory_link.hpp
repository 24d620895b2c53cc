// Two MessageLinks connected in memory, for tests of sessions and roles without sockets: messages
// cross whole and in order on later turns of the executor, a bounded amount in flight backs up a
// writer whose reader paused (as TCP's buffers do), and closing one end ends the other.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstddef>
#include <memory>
#include <string>
#include <system_error>

#include "backbone/delimited_codec.hpp"
#include "backbone/message_link.hpp"

namespace canbridge::backbone {

struct MemoryLinkOptions {
  // Bytes that may wait unread at one end before the other end's writer stops calling its source
  // (the pair's socket buffers). A write takes the source's whole batch, so an end may hold up to
  // this plus one batch.
  std::size_t capacity_bytes = 64 * 1024;
  // What crc_framed() reports: a session then behaves as over a serial line. The bytes are not
  // COBS framed (nothing in memory corrupts them).
  bool crc_framed = false;
  // The ends' names: end a's peer_name() is "<name>/b" and end b's is "<name>/a".
  std::string name = "memory";
  std::size_t max_message_size = kDefaultMaxMessageSize;
};

class MemoryLink;

struct MemoryLinkPair {
  std::shared_ptr<MemoryLink> a;
  std::shared_ptr<MemoryLink> b;
};

// Two connected, unstarted ends on `executor`.
MemoryLinkPair make_memory_link_pair(boost::asio::any_io_executor executor,
                                     MemoryLinkOptions options = {});

// One end of a memory pair. Everything it does for the other end is posted to the executor, so no
// handler ever runs inside a call on either end (wake_writer, close, a handler of the other end);
// with one executor thread the order of events is deterministic.
//
// When an end closes, the other end delivers what was already written to it and then ends with
// errc::peer_closed (what a TCP link reports at end of stream). A write to an end that has gone
// is discarded, and the next one ends the writer's link with connection_reset, as TCP's writes do
// after the peer closed: so a reader that is paused still learns that the link is gone.
class MemoryLink final : public MessageLink, public std::enable_shared_from_this<MemoryLink> {
  struct Private {};

 public:
  MemoryLink(Private, boost::asio::any_io_executor executor, std::string peer_name,
             const MemoryLinkOptions& options);
  ~MemoryLink() override;

  void start(MessageHandler on_message, Source source, ClosedHandler on_closed) override;
  void wake_writer() override;
  void pause_reading(bool paused) override;
  bool reading_paused() const noexcept override { return reading_paused_; }
  using MessageLink::close;
  void close(std::error_code reason) override;
  boost::asio::awaitable<std::error_code> async_wait_closed() override;
  boost::asio::any_io_executor executor() override { return executor_; }
  bool started() const noexcept override { return started_; }
  bool is_open() const noexcept override { return !closing_; }
  LinkCounters counters() const override { return counters_; }
  const std::string& peer_name() const noexcept override { return peer_name_; }
  bool crc_framed() const noexcept override { return options_.crc_framed; }
  // One batch per delivery turn: what the other end wrote since the last one.
  std::uint64_t input_batches() const noexcept override { return input_batches_; }
  bool input_waiting() override { return unread_bytes() > 0; }

  // Bytes written to this end and not yet delivered: what is in flight towards it.
  std::size_t unread_bytes() const noexcept { return inbox_.size() - inbox_offset_; }
  // This end's writer waits for the other end to read (its unread_bytes() reached the capacity).
  bool writer_blocked() const noexcept { return writer_blocked_; }

 private:
  friend MemoryLinkPair make_memory_link_pair(boost::asio::any_io_executor executor,
                                              MemoryLinkOptions options);

  void schedule_write();
  void write_turn();
  void schedule_delivery();
  void deliver_turn();
  // The other end's writer hands over a batch of delimited messages.
  void take(const std::string& batch);
  // The other end has ended: deliver what it wrote, then end too.
  void peer_ended();
  void handler_failed(const char* which);
  void end(std::error_code reason);
  void finish();

  boost::asio::any_io_executor executor_;
  MemoryLinkOptions options_;
  std::string peer_name_;
  std::weak_ptr<MemoryLink> peer_;
  std::string inbox_;  // delimited messages written to this end; delivered from inbox_offset_
  std::size_t inbox_offset_ = 0;
  DelimitedDecoder decoder_;
  std::string write_buffer_;
  boost::asio::steady_timer closed_;  // condition variable for async_wait_closed()
  MessageHandler on_message_;
  Source source_;
  ClosedHandler on_closed_;
  LinkCounters counters_;
  bool started_ = false;
  bool closing_ = false;   // end() ran
  bool finished_ = false;  // on_closed ran (or was posted, when closed before start)
  bool reading_paused_ = false;
  bool write_scheduled_ = false;     // a write_turn is posted
  bool delivery_scheduled_ = false;  // a deliver_turn is posted
  bool wake_requested_ = false;      // wake_writer() since the source was last called
  bool writer_blocked_ = false;      // this end's writer waits for the other end to read
  bool peer_gone_ = false;           // the other end has ended
  bool wrote_after_peer_gone_ = false;
  std::uint64_t input_batches_ = 0;
};

}  // namespace canbridge::backbone
