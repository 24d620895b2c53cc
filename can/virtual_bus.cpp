#include "can/virtual_bus.hpp"

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/error.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <chrono>
#include <limits>

namespace canbridge::can {

namespace asio = boost::asio;

namespace {
class VirtualEndpoint;
}

struct VirtualBus::Medium {
  asio::any_io_executor executor;
  std::string name;
  std::size_t rx_capacity;
  std::vector<VirtualEndpoint*> endpoints;  // registered for delivery, in connection order
  bool held = false;                        // sends wait in their sender's transmit queue
};

namespace {

constexpr std::size_t kBatchLimit = 256;

class VirtualEndpoint final : public Bus {
 public:
  VirtualEndpoint(std::shared_ptr<VirtualBus::Medium> medium, std::string name,
                  std::size_t tx_capacity)
      : medium_(std::move(medium)),
        name_(std::move(name)),
        wakeup_(medium_->executor),
        room_wake_(medium_->executor, asio::steady_timer::time_point::max()),
        tx_capacity_(tx_capacity) {
    medium_->endpoints.push_back(this);
  }
  ~VirtualEndpoint() override { detach(); }

  const std::string& name() const override { return name_; }

  asio::awaitable<std::error_code> receive_batch(std::vector<Frame>& out) override {
    while (queue_.empty()) {
      if (closed_) co_return std::make_error_code(std::errc::operation_canceled);
      wakeup_.expires_at(asio::steady_timer::time_point::max());
      co_await wakeup_.async_wait(asio::as_tuple(asio::use_awaitable));
      // The timer is a condition variable: cancel() means "frames arrived". A cancellation
      // requested by our caller must still end the wait.
      auto state = co_await asio::this_coro::cancellation_state;
      if (state.cancelled() != asio::cancellation_type::none) {
        co_return std::make_error_code(std::errc::operation_canceled);
      }
    }
    const std::size_t n = std::min(queue_.size(), kBatchLimit);
    out.insert(out.end(), queue_.begin(), queue_.begin() + static_cast<std::ptrdiff_t>(n));
    queue_.erase(queue_.begin(), queue_.begin() + static_cast<std::ptrdiff_t>(n));
    counters_.rx_frames += n;
    co_return std::error_code{};
  }

  // Unbounded unless a capacity was given; frames queue only while the medium is held.
  std::size_t send_room() const override { return closed_ ? 0 : tx_capacity_ - tx_queue_.size(); }

  asio::awaitable<std::error_code> wait_send_room(std::size_t frames) override {
    while (!closed_ && send_room() < frames) {
      room_wanted_ = frames;
      co_await room_wake_.async_wait(asio::as_tuple(asio::use_awaitable));
      room_wanted_ = 0;
      // cancel() means "room" or "closed"; a cancellation by our caller still ends the wait.
      auto state = co_await asio::this_coro::cancellation_state;
      if (state.cancelled() != asio::cancellation_type::none) {
        co_return std::make_error_code(std::errc::operation_canceled);
      }
    }
    if (closed_) co_return std::make_error_code(std::errc::operation_canceled);
    co_return std::error_code{};
  }

  bool send(const Frame& frame) override {
    if (closed_) {
      ++counters_.tx_dropped_error;
      return false;
    }
    if (medium_->held || !tx_queue_.empty()) {
      if (tx_queue_.size() >= tx_capacity_) {
        ++counters_.tx_dropped_queue;
        return false;
      }
      tx_queue_.push_back(frame);
      return true;
    }
    transmit(frame);
    return true;
  }

  // Like the loop of the default, but the run shares one timestamp (one clock read), as frames
  // one sendmmsg puts on a real bus nearly share one.
  std::size_t send(std::span<const Frame> frames) override {
    std::size_t taken = 0;
    if (!closed_ && !medium_->held && tx_queue_.empty()) {
      const auto stamp = wall_clock();
      for (; taken < frames.size(); ++taken) transmit(frames[taken], stamp);
      return taken;
    }
    while (taken < frames.size() && send(frames[taken])) ++taken;
    return taken;
  }

  // Puts up to `frames` held frames on the medium, oldest first; returns how many went.
  std::size_t release(std::size_t frames) {
    std::size_t n = 0;
    while (n < frames && !tx_queue_.empty()) {
      const Frame frame = tx_queue_.front();
      tx_queue_.pop_front();
      transmit(frame);
      ++n;
    }
    if (n != 0 && room_wanted_ != 0 && send_room() >= room_wanted_) room_wake_.cancel();
    return n;
  }

  BusCounters counters() const override { return counters_; }
  void on_state_change(std::function<void(BusState)>) override {}  // a virtual bus never errs

  void close() override {
    closed_ = true;
    counters_.tx_dropped_error += tx_queue_.size();
    tx_queue_.clear();
    detach();
    wakeup_.cancel();
    room_wake_.cancel();
  }

 private:
  static std::chrono::nanoseconds wall_clock() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::system_clock::now().time_since_epoch());
  }
  void transmit(const Frame& frame) { transmit(frame, wall_clock()); }
  void transmit(const Frame& frame, std::chrono::nanoseconds stamp) {
    ++counters_.tx_frames;
    Frame delivered = frame;
    delivered.timestamp = stamp;
    for (VirtualEndpoint* peer : medium_->endpoints) {
      if (peer != this) peer->deliver(delivered);
    }
  }

  void deliver(const Frame& frame) {
    if (queue_.size() >= medium_->rx_capacity) {
      ++counters_.rx_dropped_queue;
      loss_pending_ = true;
      return;
    }
    queue_.push_back(frame);
    if (loss_pending_) queue_.back().flags |= FrameFlags::follows_loss;
    loss_pending_ = false;
    if (queue_.size() == 1) wakeup_.cancel();
  }

  void detach() {
    auto& eps = medium_->endpoints;
    eps.erase(std::remove(eps.begin(), eps.end(), this), eps.end());
  }

  std::shared_ptr<VirtualBus::Medium> medium_;
  std::string name_;
  asio::steady_timer wakeup_;
  asio::steady_timer room_wake_;  // condition variable: room_wanted_ slots free, or closed
  std::size_t tx_capacity_;
  std::deque<Frame> tx_queue_;   // sent while the medium was held
  std::size_t room_wanted_ = 0;  // slots a wait_send_room() waits for; 0: none waits
  std::deque<Frame> queue_;
  bool loss_pending_ = false;  // a frame was dropped: flag the next one queued
  BusCounters counters_;
  bool closed_ = false;
};

}  // namespace

VirtualBus::VirtualBus(asio::any_io_executor executor, std::string name, std::size_t rx_capacity)
    : medium_(
          std::make_shared<Medium>(Medium{std::move(executor), std::move(name), rx_capacity, {}})) {
}

VirtualBus::~VirtualBus() = default;

std::unique_ptr<Bus> VirtualBus::connect(std::string endpoint_name, std::size_t tx_capacity) {
  return std::make_unique<VirtualEndpoint>(medium_, std::move(endpoint_name), tx_capacity);
}

void VirtualBus::hold(bool held) {
  medium_->held = held;
  if (!held) release_held(std::numeric_limits<std::size_t>::max());
}

void VirtualBus::release_held(std::size_t frames) {
  for (VirtualEndpoint* station : medium_->endpoints) {
    if (frames == 0) break;
    frames -= station->release(frames);
  }
}

const std::string& VirtualBus::name() const {
  return medium_->name;
}

}  // namespace canbridge::can
