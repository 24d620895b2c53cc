// Helpers for the SocketCAN system tests in the vcan rig: can-utils child processes, a plain raw
// socket observer, and an event loop runner with a deadline.
#pragma once

#include <sys/types.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::can_system {

// A child program (posix_spawnp) whose merged stdout+stderr is collected by a thread, so a
// chatty child (candump) never blocks on a full pipe. Killed on destruction.
class Child {
 public:
  explicit Child(std::vector<std::string> argv);
  ~Child();
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;

  // True once the child closed its output, i.e. exited (the tools here do not fork).
  bool finished() const;
  // Waits until the child exited; its exit status (128+signal when killed), nullopt on timeout.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  int stop();  // SIGTERM, then the exit status
  std::string output() const;
  pid_t pid() const { return pid_; }

 private:
  std::optional<int> reap();
  pid_t pid_ = -1;
  int out_fd_ = -1;
  std::thread reader_;
  mutable std::mutex mutex_;
  std::condition_variable eof_cv_;
  std::string output_;
  bool eof_ = false;
  std::optional<int> status_;
};

struct RunResult {
  int status = -1;
  std::string output;
};
// Runs a program to completion (bounded by `timeout`).
RunResult run(std::vector<std::string> argv,
              std::chrono::milliseconds timeout = std::chrono::milliseconds(10000));

// Receivers registered on `interface` in the kernel's rx_all list (/proc/net/can/rcvlist_all):
// every CAN_RAW socket without filters, candump's included.
int receivers_on(const std::string& interface);
// Bounded poll (every 2 ms, up to `timeout`) until more than `baseline` receivers are registered:
// the only readiness signal candump gives is that its socket is bound.
bool wait_for_receivers(const std::string& interface, int baseline,
                        std::chrono::milliseconds timeout = std::chrono::milliseconds(5000));

// A plain nonblocking CAN_RAW socket, independent of SocketCanBus. A socket stays bound across
// an interface down/up; it reports ENETDOWN once, which receive() skips.
class RawSocket {
 public:
  explicit RawSocket(const std::string& interface);
  ~RawSocket();
  RawSocket(const RawSocket&) = delete;
  RawSocket& operator=(const RawSocket&) = delete;
  // Next frame, or nullopt when none arrives within `timeout` (poll(2), no sleeping).
  std::optional<can::Frame> receive(std::chrono::milliseconds timeout);

 private:
  int fd_ = -1;
};

// Runs handlers until `done()` holds (true) or the deadline passes (false). `done()` is checked
// every 2 ms, so conditions outside the loop (child exits) are noticed too.
bool run_until(boost::asio::io_context& io, const std::function<bool()>& done,
               std::chrono::milliseconds timeout);

}  // namespace canbridge::can_system
