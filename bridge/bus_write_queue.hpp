// The frames waiting for room on one CAN bus, strictly first in, first out: once one frame
// waits, every later frame for that bus waits behind it, so nothing reaches the bus out of order.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <limits>
#include <span>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::bridge {

// Pure: frames and the bus's free transmit slots in, frames to write out; no bus, no clock.
class BusWriteQueue {
 public:
  // Reliable frames (SDO, EMCY, NMT, boot-ups, PDO Packets) are never dropped for want of room;
  // process data is, beyond a bound: only its latest value matters, and it keeps coming.
  enum class Lane : std::uint8_t { reliable, process_data };

  enum class Drop : std::uint8_t {
    process_data_backlog,  // process data offered while max_waiting_for_process_data waited
    larger_than_bus,       // a unit the idle bus cannot take whole (more frames than it holds)
    closed,                // waiting when the bus closed
  };
  static constexpr std::size_t kDropReasons = 3;

  struct Options {
    // Frames the idle bus's transmit queue takes (its send_room() before anything was sent).
    std::size_t bus_capacity = std::numeric_limits<std::size_t>::max();
    // Process data offered while this many frames wait is dropped.
    std::size_t max_waiting_for_process_data = 1024;
    // backlogged() turns true above high_watermark frames waiting, false again at or below
    // low_watermark: the hysteresis of the backpressure the roles apply to the backbone.
    std::size_t high_watermark = 1024;
    std::size_t low_watermark = 256;
  };

  struct Counters {
    std::uint64_t frames_written = 0;  // handed out to be written, at once or after waiting
    std::uint64_t frames_waited = 0;   // ... of those, after waiting for room
    std::uint64_t peak_waiting = 0;    // most frames waiting at once
    std::uint64_t backlogs = 0;        // times backlogged() turned true
    std::array<std::uint64_t, kDropReasons> dropped{};  // frames, by Drop
  };

  explicit BusWriteQueue(Options options);

  // Offers a unit of frames that goes on the bus whole and after everything offered before (one
  // frame, or a PDO Packet's fragments: a packet with a gap in it can pass a master's checks).
  // When nothing waits and `room` free slots take the whole unit, it is appended to `write_now`;
  // otherwise it waits. False when the unit was dropped (counted by reason).
  bool offer(std::span<const can::Frame> unit, Lane lane, std::size_t room,
             std::vector<can::Frame>& write_now);

  // Appends to `out` the waiting units from the head that fit in `room` free slots, in order.
  // Stops at the first unit that does not fit: nothing overtakes it.
  void take(std::size_t room, std::vector<can::Frame>& out);

  // Free slots the oldest waiting unit needs; 0 when nothing waits.
  std::size_t head_frames() const { return units_.empty() ? 0 : units_.front(); }
  std::size_t waiting() const { return frames_.size(); }
  bool empty() const { return frames_.empty(); }
  bool backlogged() const { return backlogged_; }

  // The bus closed: everything waiting is dropped (counted).
  void clear();

  // Removes the waiting one-frame units for which `withdrawn(frame)` is true (the others keep
  // their order) and returns how many: frames whose sender was told meanwhile that they failed
  // (SDO requests the surface aborted when the link died). Not counted as drops: the caller
  // counts them as withdrawn.
  template <typename Predicate>
  std::size_t withdraw_single_frames(Predicate withdrawn) {
    std::deque<can::Frame> frames;
    std::deque<std::size_t> units;
    std::size_t removed = 0;
    auto frame = frames_.begin();
    for (std::size_t unit : units_) {
      if (unit == 1 && withdrawn(*frame)) {
        ++removed;
      } else {
        frames.insert(frames.end(), frame, frame + static_cast<std::ptrdiff_t>(unit));
        units.push_back(unit);
      }
      frame += static_cast<std::ptrdiff_t>(unit);
    }
    frames_.swap(frames);
    units_.swap(units);
    update_backlog();
    return removed;
  }

  const Counters& counters() const { return counters_; }
  std::uint64_t dropped() const;

 private:
  void update_backlog();

  Options options_;
  std::deque<can::Frame> frames_;  // waiting, oldest first
  std::deque<std::size_t> units_;  // sizes of the waiting units, oldest first
  bool backlogged_ = false;
  Counters counters_;
};

const char* to_string(BusWriteQueue::Drop reason);

}  // namespace canbridge::bridge
