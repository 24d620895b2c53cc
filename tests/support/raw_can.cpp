#include "tests/support/raw_can.hpp"

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <system_error>
#include <thread>

namespace canbridge::test {

using namespace std::chrono_literals;

namespace {

// Waits for `events` on `fd` until `deadline`; false once it has passed.
bool poll_until(int fd, short events, std::chrono::steady_clock::time_point deadline) {
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
      deadline - std::chrono::steady_clock::now());
  if (left.count() <= 0) return false;
  pollfd p{fd, events, 0};
  ::poll(&p, 1, static_cast<int>(left.count()));
  return true;
}

}  // namespace

RawCanSocket::RawCanSocket(const std::string& interface)
    : RawCanSocket(interface, std::vector<std::uint32_t>{}) {}

RawCanSocket::RawCanSocket(const std::string& interface, const std::vector<std::uint32_t>& ids) {
  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) throw std::system_error(errno, std::system_category(), "socket(PF_CAN)");
  std::vector<can_filter> filters;
  for (std::uint32_t id : ids) filters.push_back({id, CAN_SFF_MASK | CAN_EFF_FLAG});
  // Set before bind, so that no unfiltered frame is ever queued.
  if (!filters.empty() &&
      ::setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                   static_cast<socklen_t>(filters.size() * sizeof(can_filter))) != 0) {
    const int error = errno;
    ::close(fd_);
    throw std::system_error(error, std::system_category(), "CAN_RAW_FILTER " + interface);
  }
  // Room for a flood (a test that reads while cangen -g 0 writes falls behind): 8 MiB, forced
  // where permitted (the rig runs as root), else as much as net.core.rmem_max allows.
  const int receive_buffer = 8 << 20;
  if (::setsockopt(fd_, SOL_SOCKET, SO_RCVBUFFORCE, &receive_buffer, sizeof receive_buffer) != 0) {
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer, sizeof receive_buffer);
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(::if_nametoindex(interface.c_str()));
  int error = 0;
  if (addr.can_ifindex == 0) {
    error = ENODEV;
  } else if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    error = errno;
  }
  if (error != 0) {
    ::close(fd_);
    throw std::system_error(error, std::system_category(), "bind " + interface);
  }
}

RawCanSocket::~RawCanSocket() {
  ::close(fd_);
}

void RawCanSocket::send(const can::Frame& frame) {
  can_frame cf{};
  cf.can_id = frame.id;
  if (frame.is_extended()) cf.can_id |= CAN_EFF_FLAG;
  if (frame.is_remote()) cf.can_id |= CAN_RTR_FLAG;
  if (frame.is_error()) cf.can_id |= CAN_ERR_FLAG;
  cf.len = frame.len;
  std::memcpy(cf.data, frame.data.data(), std::min<std::size_t>(frame.len, sizeof cf.data));
  const auto deadline = std::chrono::steady_clock::now() + 1s;
  for (;;) {
    const ssize_t n = ::write(fd_, &cf, sizeof cf);
    if (n == static_cast<ssize_t>(sizeof cf)) return;
    if (n >= 0 || (errno != EAGAIN && errno != ENOBUFS && errno != EINTR) ||
        !poll_until(fd_, POLLOUT, deadline)) {
      throw std::system_error(n < 0 ? errno : EIO, std::system_category(),
                              "CAN write " + can::to_string(frame));
    }
  }
}

std::optional<can::Frame> RawCanSocket::receive(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    can_frame cf;
    const ssize_t n = ::read(fd_, &cf, sizeof cf);
    if (n == static_cast<ssize_t>(sizeof cf)) {
      can::Frame f;
      f.flags =
          static_cast<std::uint8_t>(((cf.can_id & CAN_EFF_FLAG) ? can::FrameFlags::extended : 0) |
                                    ((cf.can_id & CAN_RTR_FLAG) ? can::FrameFlags::remote : 0));
      f.id = cf.can_id & ((cf.can_id & CAN_EFF_FLAG) ? CAN_EFF_MASK : CAN_SFF_MASK);
      f.len = std::min<std::uint8_t>(cf.len, 8);
      std::memcpy(f.data.data(), cf.data, f.len);
      return f;
    }
    if (n < 0 && errno != EAGAIN && errno != ENETDOWN && errno != EINTR) {
      throw std::system_error(errno, std::system_category(), "CAN read");
    }
    if (!poll_until(fd_, POLLIN, deadline)) return std::nullopt;
  }
}

FramesUntil receive_until(RawCanSocket& socket, const can::Frame& marker,
                          std::chrono::milliseconds gap) {
  FramesUntil got;
  while (auto f = socket.receive(gap)) {
    got.frames.push_back(*f);
    if (*f == marker) {
      got.marker_seen = true;
      break;
    }
  }
  return got;
}

int receivers_on(const std::string& interface) {
  std::ifstream in("/proc/net/can/rcvlist_all");
  std::string line;
  int count = 0;
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    std::string first;
    fields >> first;
    if (first == interface) ++count;
  }
  return count;
}

bool wait_for_receivers(const std::string& interface, int baseline,
                        std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (receivers_on(interface) <= baseline) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(2ms);
  }
  return true;
}

}  // namespace canbridge::test
