#include "canopen/sdo_client.hpp"

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/experimental/awaitable_operators.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <stdexcept>
#include <type_traits>
#include <utility>
#include <variant>

namespace canbridge::canopen {

namespace asio = boost::asio;

// --- SdoClientTransaction ---------------------------------------------------------------------

SdoClientTransaction::SdoClientTransaction(NodeId node, sdo::Multiplexer mux, bool upload,
                                           std::chrono::milliseconds timeout)
    : node_(node), mux_(mux), upload_(upload), timeout_(timeout) {
  if (node == 0 || node > kMaxNodeId) throw std::invalid_argument("SDO node id must be 1..127");
}

SdoClientTransaction SdoClientTransaction::upload(NodeId node, sdo::Multiplexer mux,
                                                  std::chrono::milliseconds timeout) {
  return SdoClientTransaction(node, mux, true, timeout);
}

SdoClientTransaction SdoClientTransaction::download(NodeId node, sdo::Multiplexer mux,
                                                    std::span<const std::uint8_t> data,
                                                    std::chrono::milliseconds timeout) {
  if (data.empty() || data.size() > sdo::kMaxExpedited) {
    throw std::invalid_argument("expedited SDO download needs 1..4 data bytes");
  }
  SdoClientTransaction t(node, mux, false, timeout);
  std::copy(data.begin(), data.end(), t.data_.bytes.begin());
  t.data_.size = static_cast<std::uint8_t>(data.size());
  return t;
}

can::Frame SdoClientTransaction::start(TimePoint now) {
  phase_ = Phase::waiting;
  deadline_ = now + timeout_;
  return upload_ ? sdo::upload_request(node_, mux_)
                 : sdo::download_request(node_, mux_, data_.span());
}

SdoStep SdoClientTransaction::finish(SdoResult result) {
  phase_ = Phase::done;
  return {std::nullopt, std::move(result)};
}

SdoStep SdoClientTransaction::fail_and_tell_server(SdoAbort abort) {
  SdoStep step = finish({make_error_code(abort), {}});
  step.send = sdo::abort_request(node_, mux_, abort);
  return step;
}

SdoStep SdoClientTransaction::on_frame(const can::Frame& frame, TimePoint /*now*/) {
  if (phase_ != Phase::waiting || frame.id != sdo::response_cob(node_)) return {};
  const auto response = sdo::decode_response(frame);
  if (!response) return {};
  return std::visit(
      [&](const auto& r) -> SdoStep {
        using T = std::decay_t<decltype(r)>;
        if constexpr (std::is_same_v<T, sdo::UnsupportedResponse>) {
          // Segment and block responses cannot answer an expedited initiate request.
          return fail_and_tell_server(SdoAbort::invalid_command);
        } else {
          if (r.mux != mux_) return {};  // a late answer to an earlier request
          if constexpr (std::is_same_v<T, sdo::AbortTransfer>) {
            return finish({r.error(), {}});  // an abort is never answered
          } else if constexpr (std::is_same_v<T, sdo::UploadResponse>) {
            if (!upload_) return fail_and_tell_server(SdoAbort::invalid_command);
            // The server wants a segmented upload (object longer than 4 bytes), which this client
            // does not implement; the abort frees the server's transfer state.
            if (!r.expedited) return fail_and_tell_server(SdoAbort::unsupported_access);
            const auto bytes = r.data.span();
            return finish({{}, {bytes.begin(), bytes.end()}});
          } else {
            static_assert(std::is_same_v<T, sdo::DownloadResponse>);
            if (upload_) return fail_and_tell_server(SdoAbort::invalid_command);
            return finish({});
          }
        }
      },
      *response);
}

SdoStep SdoClientTransaction::on_timeout(TimePoint now) {
  if (phase_ != Phase::waiting || now < deadline_) return {};
  return fail_and_tell_server(SdoAbort::timeout);
}

SdoStep SdoClientTransaction::abort(std::error_code reason) {
  if (phase_ == Phase::done) return {};
  const bool was_waiting = phase_ == Phase::waiting;
  SdoStep step = finish({reason, {}});
  if (was_waiting) step.send = sdo::abort_request(node_, mux_, to_abort_code(reason));
  return step;
}

// --- SdoClientChannel -------------------------------------------------------------------------

// Lives in the frame of the coroutine waiting for it; the channel's queues point at it.
struct SdoClientChannel::Pending {
  Pending(SdoClientChannel* owner, SdoClientTransaction t)
      : channel(owner), transaction(std::move(t)), timer(owner->executor_) {}
  ~Pending() {
    // Only reached while still queued when the coroutine is destroyed without finishing (its
    // io_context shut down); the channel may be gone already, which clears `channel`.
    if (channel != nullptr) channel->forget(*this);
  }
  Pending(const Pending&) = delete;
  Pending& operator=(const Pending&) = delete;

  SdoClientChannel* channel;
  SdoClientTransaction transaction;
  // Expires at the transaction's deadline while it runs; cancelled to wake the waiting coroutine
  // when it is activated or completed.
  asio::steady_timer timer;
  std::optional<SdoResult> result;
  bool active = false;
};

SdoClientChannel::SdoClientChannel(asio::any_io_executor executor, can::Bus& bus)
    : executor_(std::move(executor)), bus_(bus), stop_timer_(executor_) {}

SdoClientChannel::~SdoClientChannel() {
  for (auto& queue : queues_) {
    for (Pending* p : queue) p->channel = nullptr;
  }
}

void SdoClientChannel::set_observer(std::function<void(const can::Frame&)> observer) {
  observer_ = std::move(observer);
}

asio::awaitable<void> SdoClientChannel::run() {
  if (!stopped_) {
    using namespace asio::experimental::awaitable_operators;
    // Whichever ends first (bus failure or stop()) cancels the other.
    co_await (receive_loop() || wait_for_stop());
  }
  stopped_ = true;
  fail_all(std::make_error_code(std::errc::operation_canceled));
}

void SdoClientChannel::stop() {
  stopped_ = true;
  stop_timer_.cancel();
}

asio::awaitable<void> SdoClientChannel::wait_for_stop() {
  while (!stopped_) {
    stop_timer_.expires_at(asio::steady_timer::time_point::max());
    co_await stop_timer_.async_wait(asio::as_tuple(asio::use_awaitable));
    const auto state = co_await asio::this_coro::cancellation_state;
    if (state.cancelled() != asio::cancellation_type::none) co_return;
  }
}

asio::awaitable<void> SdoClientChannel::receive_loop() {
  std::vector<can::Frame> batch;
  for (;;) {
    batch.clear();
    if (co_await bus_.receive_batch(batch)) co_return;
    const auto now = SdoClientTransaction::Clock::now();
    for (const can::Frame& frame : batch) dispatch(frame, now);
  }
}

void SdoClientChannel::dispatch(const can::Frame& frame, SdoClientTransaction::TimePoint now) {
  if (observer_) observer_(frame);
  if (frame.is_extended() || frame.id <= cob::sdo_tx || frame.id > cob::sdo_tx + kMaxNodeId) {
    return;
  }
  auto& queue = queues_[frame.id - cob::sdo_tx];
  if (queue.empty() || !queue.front()->active) return;
  Pending& running = *queue.front();
  apply(running, running.transaction.on_frame(frame, now));
}

asio::awaitable<SdoResult> SdoClientChannel::upload(NodeId node, std::uint16_t index,
                                                    std::uint8_t sub,
                                                    std::chrono::milliseconds timeout) {
  // Not a coroutine itself: validation throws here, at the call.
  return transact(SdoClientTransaction::upload(node, {index, sub}, timeout));
}

asio::awaitable<SdoResult> SdoClientChannel::download(NodeId node, std::uint16_t index,
                                                      std::uint8_t sub,
                                                      std::span<const std::uint8_t> data,
                                                      std::chrono::milliseconds timeout) {
  // The transaction copies `data`, so the caller's buffer need not outlive the awaitable.
  return transact(SdoClientTransaction::download(node, {index, sub}, data, timeout));
}

asio::awaitable<SdoResult> SdoClientChannel::transact(SdoClientTransaction transaction) {
  if (stopped_) co_return SdoResult{std::make_error_code(std::errc::operation_canceled), {}};
  Pending pending(this, std::move(transaction));
  auto& queue = queues_[pending.transaction.node()];
  queue.push_back(&pending);
  if (queue.size() == 1) {
    activate(pending);
  } else {
    pending.timer.expires_at(asio::steady_timer::time_point::max());
  }
  while (!pending.result) {
    auto [ec] = co_await pending.timer.async_wait(asio::as_tuple(asio::use_awaitable));
    if (pending.result) break;
    const auto state = co_await asio::this_coro::cancellation_state;
    if (state.cancelled() != asio::cancellation_type::none) {
      const auto reason = std::make_error_code(std::errc::operation_canceled);
      // Tells the server only if the request went out; a queued one just leaves the queue.
      apply(pending, pending.transaction.abort(reason));
      break;
    }
    // A cancelled wait without a result means we were activated (the timer was re-armed).
    if (!ec && pending.active) {
      apply(pending, pending.transaction.on_timeout(SdoClientTransaction::Clock::now()));
    }
  }
  co_return std::move(*pending.result);
}

void SdoClientChannel::activate(Pending& pending) {
  pending.active = true;
  const can::Frame request = pending.transaction.start(SdoClientTransaction::Clock::now());
  if (!bus_.send(request)) {
    // Waiting for the timeout would only hide that the request never left. No abort frame
    // either: the server never heard of this transfer, and the queue is full anyway.
    pending.transaction.abort(std::make_error_code(std::errc::no_buffer_space));
    complete(pending, {std::make_error_code(std::errc::no_buffer_space), {}});
    return;
  }
  pending.timer.expires_at(pending.transaction.deadline());  // also wakes a queued waiter
}

void SdoClientChannel::apply(Pending& pending, SdoStep step) {
  if (step.send) bus_.send(*step.send);
  if (step.result) complete(pending, std::move(*step.result));
}

void SdoClientChannel::complete(Pending& pending, SdoResult result) {
  pending.result = std::move(result);
  pending.active = false;
  pending.timer.cancel();
  auto& queue = queues_[pending.transaction.node()];
  const bool was_running = !queue.empty() && queue.front() == &pending;
  forget(pending);
  if (was_running && !stopped_ && !queue.empty()) activate(*queue.front());
}

void SdoClientChannel::forget(Pending& pending) {
  auto& queue = queues_[pending.transaction.node()];
  queue.erase(std::remove(queue.begin(), queue.end(), &pending), queue.end());
}

void SdoClientChannel::fail_all(std::error_code error) {
  for (auto& queue : queues_) {
    while (!queue.empty()) {
      Pending& p = *queue.front();
      p.transaction.abort(error);  // no abort frame: the bus is going away
      complete(p, {error, {}});
    }
  }
}

}  // namespace canbridge::canopen
