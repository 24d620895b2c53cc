#include "bridge/bus_write_queue.hpp"

#include <algorithm>

namespace canbridge::bridge {

BusWriteQueue::BusWriteQueue(Options options) : options_(options) {
  options_.bus_capacity = std::max<std::size_t>(options_.bus_capacity, 1);
  options_.low_watermark = std::min(options_.low_watermark, options_.high_watermark);
}

bool BusWriteQueue::offer(std::span<const can::Frame> unit, Lane lane, std::size_t room,
                          std::vector<can::Frame>& write_now) {
  if (unit.empty()) return true;
  if (unit.size() > options_.bus_capacity) {
    // Waiting would block the bus forever; writing part of it would break the packet.
    counters_.dropped[static_cast<std::size_t>(Drop::larger_than_bus)] += unit.size();
    return false;
  }
  if (frames_.empty() && unit.size() <= room) {
    write_now.insert(write_now.end(), unit.begin(), unit.end());
    counters_.frames_written += unit.size();
    return true;
  }
  if (lane == Lane::process_data && frames_.size() >= options_.max_waiting_for_process_data) {
    // The newest value is the one dropped: dropping from the middle would be no better for a
    // master, and the queue stays a plain FIFO.
    counters_.dropped[static_cast<std::size_t>(Drop::process_data_backlog)] += unit.size();
    return false;
  }
  frames_.insert(frames_.end(), unit.begin(), unit.end());
  units_.push_back(unit.size());
  counters_.peak_waiting = std::max<std::uint64_t>(counters_.peak_waiting, frames_.size());
  update_backlog();
  return true;
}

void BusWriteQueue::take(std::size_t room, std::vector<can::Frame>& out) {
  std::size_t taken = 0;
  while (!units_.empty() && units_.front() <= room) {
    const std::size_t n = units_.front();
    units_.pop_front();
    room -= n;
    taken += n;
  }
  if (taken == 0) return;
  const auto end = frames_.begin() + static_cast<std::ptrdiff_t>(taken);
  out.insert(out.end(), frames_.begin(), end);
  frames_.erase(frames_.begin(), end);
  counters_.frames_written += taken;
  counters_.frames_waited += taken;
  update_backlog();
}

void BusWriteQueue::clear() {
  counters_.dropped[static_cast<std::size_t>(Drop::closed)] += frames_.size();
  frames_.clear();
  units_.clear();
  update_backlog();
}

std::uint64_t BusWriteQueue::dropped() const {
  std::uint64_t total = 0;
  for (std::uint64_t d : counters_.dropped) total += d;
  return total;
}

void BusWriteQueue::update_backlog() {
  if (!backlogged_ && frames_.size() > options_.high_watermark) {
    backlogged_ = true;
    ++counters_.backlogs;
  } else if (backlogged_ && frames_.size() <= options_.low_watermark) {
    backlogged_ = false;
  }
}

const char* to_string(BusWriteQueue::Drop reason) {
  switch (reason) {
    case BusWriteQueue::Drop::process_data_backlog:
      return "process-data-backlog";
    case BusWriteQueue::Drop::larger_than_bus:
      return "larger-than-bus";
    case BusWriteQueue::Drop::closed:
      return "closed";
  }
  return "?";
}

}  // namespace canbridge::bridge
