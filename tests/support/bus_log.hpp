// Every frame on one SocketCAN bus with its arrival time, recorded by a thread of its own, for
// rig system tests that wait for a frame or check what a bus carried.
#pragma once

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <functional>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "can/frame.hpp"
#include "tests/support/raw_can.hpp"

namespace canbridge::test {

// Every frame on one bus with its arrival time. Waits are woken by each arriving frame.
class BusLog {
 public:
  struct Entry {
    std::chrono::steady_clock::time_point at;
    can::Frame frame;
  };
  struct Found {
    Entry entry;
    std::size_t index;  // position in the log; search on from index + 1
  };

  explicit BusLog(const std::string& interface)
      : socket_(interface), reader_([this](const std::stop_token& stop) { read(stop); }) {}

  std::size_t mark() const {
    std::lock_guard lock(mutex_);
    return entries_.size();
  }
  // The first frame at or after position `from` that matches, waiting up to `timeout` for it.
  std::optional<Found> wait_for(std::size_t from,
                                const std::function<bool(const can::Frame&)>& match,
                                std::chrono::milliseconds timeout) {
    std::unique_lock lock(mutex_);
    std::optional<Found> found;
    std::size_t next = from;
    changed_.wait_for(lock, timeout, [&] {
      for (; next < entries_.size(); ++next) {
        if (match(entries_[next].frame)) {
          found = Found{entries_[next], next};
          return true;
        }
      }
      return false;
    });
    return found;
  }
  std::vector<Entry> entries(std::size_t from = 0) const {
    std::lock_guard lock(mutex_);
    return {entries_.begin() + static_cast<std::ptrdiff_t>(std::min(from, entries_.size())),
            entries_.end()};
  }

 private:
  void read(const std::stop_token& stop) {
    // The timeout only bounds how late the stop request is seen; frames wake it at once.
    while (!stop.stop_requested()) {
      auto f = socket_.receive(std::chrono::milliseconds(50));
      if (!f) continue;
      {
        std::lock_guard lock(mutex_);
        entries_.push_back({std::chrono::steady_clock::now(), *f});
      }
      changed_.notify_all();
    }
  }

  RawCanSocket socket_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::vector<Entry> entries_;
  std::jthread reader_;  // last: stopped and joined before the members it uses go
};

}  // namespace canbridge::test
