#include "tests/support/raw_can.hpp"

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstring>
#include <stdexcept>

namespace canbridge::test {

RawCanSocket::RawCanSocket(const std::string& interface) {
  fd_ = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd_ < 0) throw std::runtime_error("socket(PF_CAN) failed: " + std::string(strerror(errno)));
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(interface.c_str()));
  if (addr.can_ifindex == 0 || bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    close(fd_);
    throw std::runtime_error("cannot bind to " + interface);
  }
}

RawCanSocket::~RawCanSocket() {
  close(fd_);
}

void RawCanSocket::send(const can::Frame& frame) {
  can_frame cf{};
  cf.can_id = frame.id;
  if (frame.is_extended()) cf.can_id |= CAN_EFF_FLAG;
  if (frame.is_remote()) cf.can_id |= CAN_RTR_FLAG;
  cf.can_dlc = frame.len;
  std::memcpy(cf.data, frame.data.data(), frame.len);
  if (write(fd_, &cf, sizeof cf) != static_cast<ssize_t>(sizeof cf)) {
    throw std::runtime_error("CAN write failed: " + std::string(strerror(errno)));
  }
}

std::optional<can::Frame> RawCanSocket::receive(std::chrono::milliseconds timeout) {
  pollfd p{fd_, POLLIN, 0};
  if (poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return std::nullopt;
  can_frame cf{};
  if (read(fd_, &cf, sizeof cf) != static_cast<ssize_t>(sizeof cf)) return std::nullopt;
  can::Frame f;
  f.flags = static_cast<std::uint8_t>(((cf.can_id & CAN_EFF_FLAG) ? can::FrameFlags::extended : 0) |
                                      ((cf.can_id & CAN_RTR_FLAG) ? can::FrameFlags::remote : 0));
  f.id = cf.can_id & ((cf.can_id & CAN_EFF_FLAG) ? CAN_EFF_MASK : CAN_SFF_MASK);
  f.len = cf.can_dlc > 8 ? 8 : cf.can_dlc;
  std::memcpy(f.data.data(), cf.data, f.len);
  return f;
}

}  // namespace canbridge::test
