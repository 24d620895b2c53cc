// Plain SocketCAN access for system tests, deliberately independent of the project's own
// SocketCanBus: a raw socket to observe and send, and the kernel's list of receivers.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::test {

// A nonblocking CAN_RAW socket without filters. It stays bound across an interface down/up; it
// reports ENETDOWN once, which receive() skips.
class RawCanSocket {
 public:
  explicit RawCanSocket(const std::string& interface);
  // Receives only standard frames (data or remote) with one of `ids`: the kernel filters, so a
  // busy bus (PDO Packet streams) cannot overflow the queue with frames the reader would skip.
  RawCanSocket(const std::string& interface, const std::vector<std::uint32_t>& ids);
  ~RawCanSocket();
  RawCanSocket(const RawCanSocket&) = delete;
  RawCanSocket& operator=(const RawCanSocket&) = delete;

  // Writes one frame (waiting up to a second for room in the socket's queue); throws on error.
  void send(const can::Frame& frame);
  // Next frame, or nullopt when none arrives within `timeout` (poll(2), no sleeping).
  std::optional<can::Frame> receive(std::chrono::milliseconds timeout);

 private:
  int fd_ = -1;
};

// What receive_until() read: every frame in arrival order, the marker last if it came.
struct FramesUntil {
  std::vector<can::Frame> frames;
  bool marker_seen = false;
};
// Reads frames from `socket` up to and including `marker`, each within `gap` of the one before;
// stops early (marker_seen false) once a gap passes without a frame. The caller asserts.
FramesUntil receive_until(RawCanSocket& socket, const can::Frame& marker,
                          std::chrono::milliseconds gap);

// Receivers registered on `interface` in the kernel's rx_all list (/proc/net/can/rcvlist_all):
// every CAN_RAW socket without filters, candump's included.
int receivers_on(const std::string& interface);
// Bounded poll (every 2 ms, up to `timeout`) until more than `baseline` receivers are registered:
// the only readiness signal candump gives is that its socket is bound, and /proc offers no change
// notification.
bool wait_for_receivers(const std::string& interface, int baseline,
                        std::chrono::milliseconds timeout = std::chrono::milliseconds(5000));

}  // namespace canbridge::test
