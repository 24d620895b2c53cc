// Runs simulated nodes on a can::Bus: one receive loop feeds every node, one timer serves the
// earliest node deadline (heartbeats, PDO timers, traffic). The I/O shell around the pure SimNode
// cores.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstdint>
#include <memory>
#include <vector>

#include "can/bus.hpp"
#include "sim/sim_node.hpp"

namespace canbridge::sim {

class NodeRunner {
 public:
  NodeRunner(boost::asio::any_io_executor executor, can::Bus& bus);
  NodeRunner(const NodeRunner&) = delete;
  NodeRunner& operator=(const NodeRunner&) = delete;

  // Adds a node. Nodes added before run() boot when it starts; nodes added while it runs boot at
  // once (a node joining a live bus). The reference stays valid for the runner's lifetime.
  // Throws std::invalid_argument for a spec the node kind cannot honour.
  SimNode& add(const NodeSpec& spec);
  const std::vector<std::unique_ptr<SimNode>>& nodes() const { return nodes_; }

  // Boots the nodes, then serves the bus until stop() or until the bus fails (e.g. closed).
  // Call once, on the executor's thread like every other member.
  boost::asio::awaitable<void> run();
  void stop();

  // Replies the bus refused (transmit queue full); the node does not retry, like a real one.
  std::uint64_t dropped_frames() const { return dropped_frames_; }

 private:
  boost::asio::awaitable<void> receive_loop();
  boost::asio::awaitable<void> deadline_loop();
  void send_all(const std::vector<can::Frame>& frames);
  void boot(SimNode& node);
  SimNode::TimePoint earliest_deadline() const;
  void reschedule();

  can::Bus& bus_;
  boost::asio::steady_timer timer_;
  std::vector<std::unique_ptr<SimNode>> nodes_;
  bool running_ = false;
  bool stopped_ = false;
  std::uint64_t dropped_frames_ = 0;
};

}  // namespace canbridge::sim
