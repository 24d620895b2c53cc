// The wait between reconnection attempts of a backbone client: exponential from a minimum to a
// maximum, back to the minimum after a success, so a dead peer costs little and a healthy one
// reconnects at once.
#pragma once

#include <algorithm>
#include <chrono>

namespace canbridge::backbone {

class ReconnectBackoff {
 public:
  // A minimum below 1 ms is raised to 1 ms (no busy loop), a maximum below the minimum to it.
  ReconnectBackoff(std::chrono::milliseconds min, std::chrono::milliseconds max)
      : min_(std::max(min, std::chrono::milliseconds{1})), max_(std::max(max, min_)), next_(min_) {}

  // The wait before the next attempt; each call doubles the following one, up to the maximum.
  std::chrono::milliseconds next() {
    const auto wait = next_;
    next_ = std::min(next_ * 2, max_);
    return wait;
  }
  // The wait the next call returns, for logs.
  std::chrono::milliseconds peek() const { return next_; }
  // A connection succeeded: the next failure waits the minimum again.
  void reset() { next_ = min_; }
  std::chrono::milliseconds max() const { return max_; }

 private:
  std::chrono::milliseconds min_;
  std::chrono::milliseconds max_;
  std::chrono::milliseconds next_;
};

}  // namespace canbridge::backbone
