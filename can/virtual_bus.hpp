// An in-process CAN medium: frames sent by one endpoint reach every other endpoint, in order, never
// echoed. For unit tests and the demo only; real proofs use SocketCAN on vcan.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <deque>
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

  // A new station on this medium; it may outlive the VirtualBus object.
  std::unique_ptr<Bus> connect(std::string endpoint_name);

  const std::string& name() const;

  struct Medium;  // shared between the bus and its endpoints

 private:
  std::shared_ptr<Medium> medium_;
};

}  // namespace canbridge::can
