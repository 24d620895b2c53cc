#include "bridge/loop_guard.hpp"

namespace canbridge::bridge {

LoopGuard::LoopGuard(std::chrono::milliseconds window, std::size_t capacity)
    : window_(window), capacity_(capacity == 0 ? 1 : capacity) {
  // Reserved for the whole bound (~70 KiB at 8,192 frames), although memory is otherwise kept to
  // what is used: without it the psk burst crossed slower in an ad-hoc A/B in the qemu rig
  // (commit a26d7e8 has its figures), for reasons not found.
  live_.reserve(capacity_);
}

// FNV-1a over what makes two frames the same on the wire (timestamps do not).
std::uint64_t LoopGuard::key_of(const can::Frame& frame) {
  std::uint64_t h = 1469598103934665603ull;
  auto mix = [&h](std::uint8_t byte) {
    h ^= byte;
    h *= 1099511628211ull;
  };
  for (int shift = 0; shift < 32; shift += 8) mix(static_cast<std::uint8_t>(frame.id >> shift));
  mix(frame.flags & ~can::FrameFlags::follows_loss);  // the receiver's mark, not the frame's
  mix(frame.len);
  for (std::uint8_t b : frame.payload()) mix(b);
  return h;
}

void LoopGuard::forget_front() {
  if (!ring_.front().echoed) {
    auto it = live_.find(ring_.front().key);
    if (it != live_.end() && --it->second == 0) live_.erase(it);
  }
  ring_.pop_front();
}

void LoopGuard::forget_old(Clock::time_point now) {
  while (!ring_.empty() && now - ring_.front().at > window_) forget_front();
}

void LoopGuard::wrote(const can::Frame& frame, Clock::time_point now) {
  forget_old(now);
  if (ring_.size() >= capacity_) forget_front();
  const std::uint64_t key = key_of(frame);
  ring_.push_back({key, now, false});
  ++live_[key];
}

bool LoopGuard::is_echo(const can::Frame& frame, Clock::time_point now) {
  // Called for every frame read; most buses see far more frames than the bridge writes to
  // them, so the usual case (nothing written lately) costs no hash and no lookup.
  if (live_.empty()) return false;
  forget_old(now);
  const std::uint64_t key = key_of(frame);
  auto it = live_.find(key);
  if (it == live_.end()) return false;
  if (--it->second == 0) live_.erase(it);
  // Recognised once: the oldest matching write is used up, so a frame written twice may come
  // back twice, and a third identical frame is a new one. Echoes are rare (a loop is cut at the
  // first), so this scan stays off the hot path.
  for (Written& w : ring_) {
    if (!w.echoed && w.key == key) {
      w.echoed = true;
      break;
    }
  }
  ++echoes_;
  return true;
}

}  // namespace canbridge::bridge
