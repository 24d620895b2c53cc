// Remembers, for a short while, the frames the bridge wrote to one bus, so that the same frame
// read back from that bus (echoed by a gateway daemon, a second bridge, a loop in the wiring) is
// recognised and never forwarded again: without it, one echo turns into a frame storm.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <unordered_map>

#include "can/frame.hpp"

namespace canbridge::bridge {

// Pure: the caller passes the time. Bounded: at most `capacity` frames are remembered.
class LoopGuard {
 public:
  using Clock = std::chrono::steady_clock;

  explicit LoopGuard(std::chrono::milliseconds window = std::chrono::milliseconds{500},
                     std::size_t capacity = 8192);

  // The bridge wrote `frame` to the bus at `now`.
  void wrote(const can::Frame& frame, Clock::time_point now);
  // Whether `frame`, read from the bus at `now`, is one the bridge wrote there within the
  // window (each written frame is recognised once); counted.
  bool is_echo(const can::Frame& frame, Clock::time_point now);

  std::uint64_t echoes() const { return echoes_; }
  std::size_t remembered() const { return ring_.size(); }

 private:
  struct Written {
    std::uint64_t key;
    Clock::time_point at;
    bool echoed = false;
  };
  static std::uint64_t key_of(const can::Frame& frame);
  void forget_old(Clock::time_point now);
  void forget_front();

  std::chrono::milliseconds window_;
  std::size_t capacity_;
  std::deque<Written> ring_;                               // in writing order
  std::unordered_map<std::uint64_t, std::uint32_t> live_;  // key -> entries not yet echoed
  std::uint64_t echoes_ = 0;
};

}  // namespace canbridge::bridge
