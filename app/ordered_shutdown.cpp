#include "app/ordered_shutdown.hpp"

#include <spdlog/spdlog.h>

#include <csignal>

namespace canbridge::bridge {

OrderedShutdown::OrderedShutdown(boost::asio::io_context& io, std::function<void()> stop_children,
                                 std::chrono::milliseconds grace)
    : io_(io),
      signals_(io, SIGINT, SIGTERM),
      stop_children_(std::move(stop_children)),
      grace_(grace) {
  signals_.async_wait([this](boost::system::error_code ec, int signal) {
    if (ec) return;
    spdlog::info("signal {}: shutting down", signal);
    trigger();
  });
}

void OrderedShutdown::trigger() {
  if (triggered_) return;
  triggered_ = true;
  signals_.cancel();
  stop_children_();
  io_.stop();  // run() continues with the bounded drain
}

bool OrderedShutdown::run() {
  io_.run();
  if (!triggered_) return true;  // every loop ended on its own
  // Children closed their sockets; their loops finish within a few handlers. Whatever is still
  // pending after the grace time (a peer that never completes a close, say) must not keep the
  // process alive.
  io_.restart();
  io_.run_for(grace_);
  if (io_.stopped()) return true;
  spdlog::warn("shutdown: loops still busy after {} ms: stopping anyway", grace_.count());
  io_.stop();
  return false;
}

}  // namespace canbridge::bridge
