// A plain blocking SocketCAN raw socket for system tests: an independent observer and sender on
// a real interface, deliberately not the project's own SocketCanBus.
#pragma once

#include <chrono>
#include <optional>
#include <string>

#include "can/frame.hpp"

namespace canbridge::test {

class RawCanSocket {
 public:
  explicit RawCanSocket(const std::string& interface);
  ~RawCanSocket();
  RawCanSocket(const RawCanSocket&) = delete;
  RawCanSocket& operator=(const RawCanSocket&) = delete;

  void send(const can::Frame& frame);
  // Next frame, or nullopt when none arrives before the timeout.
  std::optional<can::Frame> receive(std::chrono::milliseconds timeout);

 private:
  int fd_ = -1;
};

}  // namespace canbridge::test
