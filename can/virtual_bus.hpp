// An in-process CAN medium: frames sent by one endpoint reach every other endpoint, in order, never
// echoed. For unit tests and the demo only; real proofs use SocketCAN on vcan.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <deque>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "can/bus.hpp"

namespace canbridge::can {

class VirtualBus {
 public:
  // rx_capacity bounds each endpoint's receive queue; overflow is counted as rx_dropped_queue.
  VirtualBus(boost::asio::any_io_executor executor, std::string name,
             std::size_t rx_capacity = 1u << 16);
  ~VirtualBus();
  VirtualBus(const VirtualBus&) = delete;
  VirtualBus& operator=(const VirtualBus&) = delete;

  // A new station on this medium; it may outlive the VirtualBus object. `tx_capacity` bounds its
  // transmit queue, which fills only while the medium is held (send() refuses beyond it).
  std::unique_ptr<Bus> connect(std::string endpoint_name,
                               std::size_t tx_capacity = std::numeric_limits<std::size_t>::max());

  // A bus too busy to take frames, for tests of writers that wait for room: while held, sent
  // frames stay in their sender's transmit queue. release_held() lets up to `frames` of them
  // through (per sender in order, senders in connection order) and keeps the medium held;
  // hold(false) lets all of them through and makes sends immediate again.
  void hold(bool held);
  void release_held(std::size_t frames);

  const std::string& name() const;

  struct Medium;  // shared between the bus and its endpoints

 private:
  std::shared_ptr<Medium> medium_;
};

}  // namespace canbridge::can
