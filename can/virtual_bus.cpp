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
};

namespace {

constexpr std::size_t kBatchLimit = 256;

class VirtualEndpoint final : public Bus {
 public:
  VirtualEndpoint(std::shared_ptr<VirtualBus::Medium> medium, std::string name)
      : medium_(std::move(medium)), name_(std::move(name)), wakeup_(medium_->executor) {
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

  // Delivery is immediate: only a closed endpoint refuses.
  std::size_t send_room() const override {
    return closed_ ? 0 : std::numeric_limits<std::size_t>::max();
  }

  bool send(const Frame& frame) override {
    if (closed_) {
      ++counters_.tx_dropped_error;
      return false;
    }
    ++counters_.tx_frames;
    Frame delivered = frame;
    delivered.timestamp = std::chrono::duration_cast<std::chrono::nanoseconds>(
        std::chrono::system_clock::now().time_since_epoch());
    for (VirtualEndpoint* peer : medium_->endpoints) {
      if (peer != this) peer->deliver(delivered);
    }
    return true;
  }

  BusCounters counters() const override { return counters_; }
  void on_state_change(std::function<void(BusState)>) override {}  // a virtual bus never errs

  void close() override {
    closed_ = true;
    detach();
    wakeup_.cancel();
  }

 private:
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

std::unique_ptr<Bus> VirtualBus::connect(std::string endpoint_name) {
  return std::make_unique<VirtualEndpoint>(medium_, std::move(endpoint_name));
}

const std::string& VirtualBus::name() const {
  return medium_->name;
}

}  // namespace canbridge::can
