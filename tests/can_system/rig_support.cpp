#include "tests/can_system/rig_support.hpp"

#include <fcntl.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/steady_timer.hpp>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <system_error>

extern char** environ;

namespace canbridge::can_system {

using namespace std::chrono_literals;

Child::Child(std::vector<std::string> argv) {
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) throw std::system_error(errno, std::system_category(), "pipe");
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[1], 1);
  posix_spawn_file_actions_adddup2(&actions, fds[1], 2);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  std::vector<char*> args;
  for (std::string& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  const int rc = ::posix_spawnp(&pid_, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[1]);
  if (rc != 0) {
    ::close(fds[0]);
    throw std::system_error(rc, std::system_category(), "posix_spawnp " + argv[0]);
  }
  out_fd_ = fds[0];
  reader_ = std::thread([this] {
    char buf[65536];
    for (;;) {
      const ssize_t n = ::read(out_fd_, buf, sizeof buf);
      if (n < 0 && errno == EINTR) continue;
      std::lock_guard lock(mutex_);
      if (n <= 0) {
        eof_ = true;
        eof_cv_.notify_all();
        return;
      }
      output_.append(buf, static_cast<std::size_t>(n));
    }
  });
}

Child::~Child() {
  if (!status_) {
    ::kill(pid_, SIGKILL);
    reap();
  }
  if (reader_.joinable()) reader_.join();
  ::close(out_fd_);
}

bool Child::finished() const {
  std::lock_guard lock(mutex_);
  return eof_;
}

std::optional<int> Child::reap() {
  if (status_) return status_;
  int status = 0;
  while (::waitpid(pid_, &status, 0) < 0) {
    if (errno != EINTR) return std::nullopt;
  }
  status_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return status_;
}

std::optional<int> Child::wait(std::chrono::milliseconds timeout) {
  {
    std::unique_lock lock(mutex_);
    if (!eof_cv_.wait_for(lock, timeout, [this] { return eof_; })) return std::nullopt;
  }
  return reap();
}

int Child::stop() {
  if (!status_) ::kill(pid_, SIGTERM);
  if (auto s = wait(5000ms)) return *s;
  ::kill(pid_, SIGKILL);
  return reap().value_or(-1);
}

std::string Child::output() const {
  std::lock_guard lock(mutex_);
  return output_;
}

RunResult run(std::vector<std::string> argv, std::chrono::milliseconds timeout) {
  Child child(std::move(argv));
  RunResult r;
  auto status = child.wait(timeout);
  r.status = status ? *status : child.stop();
  r.output = child.output();
  return r;
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
    std::this_thread::sleep_for(2ms);  // bounded poll: /proc offers no change notification
  }
  return true;
}

RawSocket::RawSocket(const std::string& interface) {
  fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd_ < 0) throw std::system_error(errno, std::system_category(), "socket");
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(::if_nametoindex(interface.c_str()));
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    throw std::system_error(errno, std::system_category(), "bind " + interface);
  }
}

RawSocket::~RawSocket() {
  ::close(fd_);
}

std::optional<can::Frame> RawSocket::receive(std::chrono::milliseconds timeout) {
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
      throw std::system_error(errno, std::system_category(), "read");
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return std::nullopt;
    pollfd p{fd_, POLLIN, 0};
    ::poll(&p, 1, static_cast<int>(left.count()));
  }
}

bool run_until(boost::asio::io_context& io, const std::function<bool()>& done,
               std::chrono::milliseconds timeout) {
  if (done()) return true;
  // Checked on a 2 ms tick rather than after every handler: run_one_for() reads the clock per
  // handler, a system call in user-mode Linux that would slow the loop under test.
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  bool met = false;
  boost::asio::steady_timer tick(io);
  std::function<void()> arm = [&] {
    tick.expires_after(2ms);
    tick.async_wait([&](boost::system::error_code ec) {
      if (ec) return;
      met = done();
      if (met || std::chrono::steady_clock::now() > deadline) {
        io.stop();
      } else {
        arm();
      }
    });
  };
  arm();
  io.restart();
  io.run();
  // Let the tick's handler finish before `tick` and the captures go away.
  tick.cancel();
  io.restart();
  io.poll();
  return met || done();
}

}  // namespace canbridge::can_system
