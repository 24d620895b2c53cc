#include "sim/node_runner.hpp"

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/experimental/awaitable_operators.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>

namespace canbridge::sim {

namespace asio = boost::asio;
using Clock = SimNode::Clock;

NodeRunner::NodeRunner(asio::any_io_executor executor, can::Bus& bus)
    : bus_(bus), timer_(std::move(executor)) {}

SimNode& NodeRunner::add(const NodeSpec& spec) {
  nodes_.push_back(std::make_unique<SimNode>(spec));
  SimNode& node = *nodes_.back();
  if (running_) {
    boot(node);
    reschedule();
  }
  return node;
}

void NodeRunner::boot(SimNode& node) {
  send_all(node.boot(Clock::now()));
}

void NodeRunner::send_all(const std::vector<can::Frame>& frames) {
  for (const can::Frame& frame : frames) {
    if (!bus_.send(frame)) ++dropped_frames_;
  }
}

SimNode::TimePoint NodeRunner::earliest_deadline() const {
  auto earliest = SimNode::TimePoint::max();
  for (const auto& node : nodes_) earliest = std::min(earliest, node->next_deadline());
  return earliest;
}

void NodeRunner::reschedule() {
  // Only an earlier deadline needs the timer moved; a later one just costs one idle wake-up.
  if (earliest_deadline() < timer_.expiry()) timer_.cancel();
}

asio::awaitable<void> NodeRunner::run() {
  if (stopped_) co_return;
  running_ = true;
  for (const auto& node : nodes_) boot(*node);
  using namespace asio::experimental::awaitable_operators;
  // Whichever ends first (bus failure, or stop() ending the deadline loop) cancels the other.
  co_await (receive_loop() || deadline_loop());
  running_ = false;
  stopped_ = true;
}

void NodeRunner::stop() {
  stopped_ = true;
  timer_.cancel();
}

asio::awaitable<void> NodeRunner::receive_loop() {
  std::vector<can::Frame> batch;
  for (;;) {
    batch.clear();
    if (co_await bus_.receive_batch(batch)) co_return;
    const auto now = Clock::now();
    for (const can::Frame& frame : batch) {
      // Index loop: a reply never adds nodes, but stays correct if a future handler does.
      for (std::size_t i = 0; i < nodes_.size(); ++i) send_all(nodes_[i]->on_frame(frame, now));
    }
    reschedule();  // e.g. a 1017h write or a reset moved a heartbeat
  }
}

asio::awaitable<void> NodeRunner::deadline_loop() {
  while (!stopped_) {
    const auto now = Clock::now();
    for (const auto& node : nodes_) send_all(node->on_tick(now));
    timer_.expires_at(earliest_deadline());
    co_await timer_.async_wait(asio::as_tuple(asio::use_awaitable));
    const auto state = co_await asio::this_coro::cancellation_state;
    if (state.cancelled() != asio::cancellation_type::none) co_return;
    // Otherwise: the deadline came, or reschedule()/stop() woke us; the loop sorts out which.
  }
}

}  // namespace canbridge::sim
