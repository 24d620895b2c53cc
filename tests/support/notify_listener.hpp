// The service manager's end of sd_notify(3) for tests: a datagram socket bound at a path or an
// abstract "@name", whose messages are received with deadlines (header-only).
#pragma once

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <string>

namespace canbridge::test {

class NotifyListener {
 public:
  // `address`: a filesystem path (replaced if it exists) or "@name" for an abstract socket.
  explicit NotifyListener(std::string address) : address_(std::move(address)) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0) throw std::runtime_error("socket: " + std::string(std::strerror(errno)));
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    if (address_.size() >= sizeof a.sun_path) throw std::runtime_error("too long: " + address_);
    std::memcpy(a.sun_path, address_.data(), address_.size());
    if (address_.front() == '@') {
      a.sun_path[0] = '\0';
    } else {
      ::unlink(address_.c_str());
    }
    const auto length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + address_.size());
    if (::bind(fd_, reinterpret_cast<const sockaddr*>(&a), length) != 0) {
      throw std::runtime_error("bind " + address_ + ": " + std::strerror(errno));
    }
  }
  ~NotifyListener() {
    ::close(fd_);
    if (address_.front() != '@') ::unlink(address_.c_str());
  }
  NotifyListener(const NotifyListener&) = delete;
  NotifyListener& operator=(const NotifyListener&) = delete;

  const std::string& address() const { return address_; }

  // The next message, or nullopt when none arrives within `timeout`.
  std::optional<std::string> receive(std::chrono::milliseconds timeout) {
    pollfd p{fd_, POLLIN, 0};
    int ready = 0;
    do {
      ready = ::poll(&p, 1, static_cast<int>(timeout.count()));
    } while (ready < 0 && errno == EINTR);
    if (ready <= 0) return std::nullopt;
    char buffer[4096];
    const ssize_t n = ::recv(fd_, buffer, sizeof buffer, MSG_DONTWAIT);
    if (n < 0) return std::nullopt;
    return std::string(buffer, static_cast<std::size_t>(n));
  }

  // Waits for a message equal to `message`, skipping others; false when none came in time.
  bool wait_for(const std::string& message, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) return false;
      auto m = receive(left);
      if (!m) return false;
      if (*m == message) return true;
    }
  }

  // Discards whatever has arrived; returns how many messages equal to `message` were among them.
  int drain(const std::string& message = "WATCHDOG=1") {
    int count = 0;
    while (auto m = receive(std::chrono::milliseconds(0))) {
      if (*m == message) ++count;
    }
    return count;
  }

 private:
  std::string address_;
  int fd_ = -1;
};

}  // namespace canbridge::test
