// Ordered shutdown for a role process: on SIGINT/SIGTERM stop the children, then give the loop a
// bounded time to drain before stopping it outright.
#pragma once

#include <boost/asio/io_context.hpp>
#include <boost/asio/signal_set.hpp>
#include <chrono>
#include <functional>

namespace canbridge::bridge {

class OrderedShutdown {
 public:
  OrderedShutdown(boost::asio::io_context& io, std::function<void()> stop_children,
                  std::chrono::milliseconds grace = std::chrono::milliseconds(2000));

  // Runs the loop until shutdown, then lets it drain for at most the grace time. Returns false
  // if work was still pending when the grace time ran out.
  bool run();

  // Also callable directly (e.g. when the demo has finished).
  void trigger();
  bool triggered() const { return triggered_; }

 private:
  boost::asio::io_context& io_;
  boost::asio::signal_set signals_;
  std::function<void()> stop_children_;
  std::chrono::milliseconds grace_;
  bool triggered_ = false;
};

}  // namespace canbridge::bridge
