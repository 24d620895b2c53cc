// Expedited SDO client: a pure per-request state machine (frames and an injected clock in, frames
// and a result out) and SdoClientChannel, the thin coroutine layer that runs it on a can::Bus.
#pragma once

#include <array>
#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <span>
#include <system_error>
#include <vector>

#include "can/bus.hpp"
#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_abort.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::canopen {

struct SdoResult {
  // Empty on success. SdoAbort values for aborts (received, or decided locally such as timeout);
  // std::errc values for channel failures (stopped, transmit queue full).
  std::error_code error;
  std::vector<std::uint8_t> data;  // the uploaded bytes; empty for downloads
  bool ok() const { return !error; }
};

// What one input did to a transaction.
struct SdoStep {
  std::optional<can::Frame> send;   // to transmit now: an abort telling the server we gave up
  std::optional<SdoResult> result;  // set once, when the transaction ends
};

// One expedited upload or download with node `node`, from request to result. Responses on the
// node's channel whose multiplexer differs from the request are ignored: they are late answers to
// an earlier, timed-out request and must not complete this one.
class SdoClientTransaction {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // Throw std::invalid_argument for a node outside 1..127 or download data outside 1..4 bytes
  // (segmented transfers are not implemented).
  static SdoClientTransaction upload(NodeId node, sdo::Multiplexer mux,
                                     std::chrono::milliseconds timeout);
  static SdoClientTransaction download(NodeId node, sdo::Multiplexer mux,
                                       std::span<const std::uint8_t> data,
                                       std::chrono::milliseconds timeout);

  NodeId node() const { return node_; }
  sdo::Multiplexer mux() const { return mux_; }
  bool is_upload() const { return upload_; }

  // The request to send; the response is due by now + timeout.
  can::Frame start(TimePoint now);
  // Any received frame; frames not for this transaction give an empty step.
  SdoStep on_frame(const can::Frame& frame, TimePoint now);
  // Ends the transaction with SdoAbort::timeout (and an abort frame to the server) once
  // now >= deadline(); an early call changes nothing.
  SdoStep on_timeout(TimePoint now);
  // Gives up for `reason` (e.g. the caller went away), telling the server.
  SdoStep abort(std::error_code reason);

  // TimePoint::max() unless a response is awaited.
  TimePoint deadline() const { return phase_ == Phase::waiting ? deadline_ : TimePoint::max(); }
  bool finished() const { return phase_ == Phase::done; }

 private:
  enum class Phase : std::uint8_t { idle, waiting, done };

  SdoClientTransaction(NodeId node, sdo::Multiplexer mux, bool upload,
                       std::chrono::milliseconds timeout);
  SdoStep finish(SdoResult result);
  SdoStep fail_and_tell_server(SdoAbort abort);

  NodeId node_;
  sdo::Multiplexer mux_;
  bool upload_;
  std::chrono::milliseconds timeout_;
  sdo::ExpeditedData data_;  // download payload
  Phase phase_ = Phase::idle;
  TimePoint deadline_{};
};

// Owns the receive loop of one bus and runs SDO client transactions on it. Requests to the same
// node are queued and run one at a time (CiA 301 allows one transfer per SDO channel); requests to
// different nodes run concurrently. Every call must come from the executor's thread.
class SdoClientChannel {
 public:
  SdoClientChannel(boost::asio::any_io_executor executor, can::Bus& bus);
  ~SdoClientChannel();
  SdoClientChannel(const SdoClientChannel&) = delete;
  SdoClientChannel& operator=(const SdoClientChannel&) = delete;

  // The receive loop. Returns after stop() or when the bus fails (e.g. closed); pending and later
  // requests then complete with std::errc::operation_canceled. Call once.
  boost::asio::awaitable<void> run();
  void stop();

  // `timeout` counts from when the request is sent, not from the call: a request queued behind
  // another to the same node does not lose its time waiting. Arguments are validated (and copied)
  // before the returned awaitable starts; invalid ones throw std::invalid_argument.
  boost::asio::awaitable<SdoResult> upload(NodeId node, std::uint16_t index, std::uint8_t sub,
                                           std::chrono::milliseconds timeout);
  boost::asio::awaitable<SdoResult> download(NodeId node, std::uint16_t index, std::uint8_t sub,
                                             std::span<const std::uint8_t> data,
                                             std::chrono::milliseconds timeout);

  // Sees every received frame before SDO dispatch: the channel owns the bus's only receive, so
  // this is how its owner also watches boot-ups and heartbeats. Must not destroy the channel.
  void set_observer(std::function<void(const can::Frame&)> observer);

 private:
  struct Pending;

  boost::asio::awaitable<SdoResult> transact(SdoClientTransaction transaction);
  boost::asio::awaitable<void> receive_loop();
  boost::asio::awaitable<void> wait_for_stop();
  void dispatch(const can::Frame& frame, SdoClientTransaction::TimePoint now);
  void activate(Pending& pending);
  void apply(Pending& pending, SdoStep step);
  void complete(Pending& pending, SdoResult result);
  void forget(Pending& pending);
  void fail_all(std::error_code error);

  boost::asio::any_io_executor executor_;
  can::Bus& bus_;
  boost::asio::steady_timer stop_timer_;
  bool stopped_ = false;
  std::function<void(const can::Frame&)> observer_;
  // Per node: the running transaction first, then the queued ones.
  std::array<std::deque<Pending*>, kMaxNodeId + 1> queues_;
};

}  // namespace canbridge::canopen
