// Writes one CAN bus's outgoing frames through a BusWriteQueue: at once while the bus has room,
// otherwise in order as room appears (awaited on the bus, never polled).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "bridge/bus_write_queue.hpp"
#include "bridge/delivery_class.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

// The lane a frame from the backbone waits in for its bus: process data (plain PDOs, SYNC, TIME,
// heartbeat states) may be dropped while the bus is backed up; everything else waits its turn.
inline BusWriteQueue::Lane bus_lane_of(const can::Frame& frame) {
  const DeliveryClass delivery = classify(frame, {});
  return delivery == DeliveryClass::process_data || delivery == DeliveryClass::latest_value
             ? BusWriteQueue::Lane::process_data
             : BusWriteQueue::Lane::reliable;
}

// The most frames one backbone message brings: an outbox never builds a batch above 4096 bytes
// (app/tuning_from_options.hpp caps max_batch_bytes there), and a frame takes at least its
// 2-byte head in it.
inline constexpr std::size_t kMaxFramesPerBackboneMessage = 4096 / 2;

// Options for a bus fed from the backbone, whose owner stops reading the backbone while the queue
// is backlogged(). A link stops delivering between messages, so once the pause engages at most
// the rest of one message still arrives: process data is dropped only beyond that, which makes
// the pause, not a drop, the answer to a bus slower than the link.
inline BusWriteQueue::Options backbone_fed_write_options() {
  BusWriteQueue::Options options;
  options.max_waiting_for_process_data = options.high_watermark + kMaxFramesPerBackboneMessage;
  return options;
}

class BusWriter {
 public:
  // Frames just handed to the bus, in bus order (loop guards, counters, NMT bookkeeping).
  using Written = std::function<void(std::span<const can::Frame> frames)>;
  // The queue's backlogged() changed: the owner pauses or resumes what feeds this bus.
  using BacklogChanged = std::function<void(bool backlogged)>;

  // `options.bus_capacity` is taken from the bus (its send_room() now, while it is idle).
  BusWriter(boost::asio::any_io_executor executor, can::Bus& bus, BusWriteQueue::Options options,
            Written on_written, BacklogChanged on_backlog_changed);
  BusWriter(const BusWriter&) = delete;
  BusWriter& operator=(const BusWriter&) = delete;

  // Starts the coroutine that writes waiting frames as room appears; it ends when the bus closes
  // or stop() is called. Let the executor run after either before destroying the writer.
  void start();
  void stop();

  // One frame, or a unit that goes whole (BusWriteQueue::offer). False when dropped (counted).
  bool write(const can::Frame& frame, BusWriteQueue::Lane lane);
  bool write(std::span<const can::Frame> unit, BusWriteQueue::Lane lane);
  // A run of frames, each a unit of its own in its lane (bus_lane_of), in order: as write(frame,
  // lane) for each, but what can go at once goes with one batch send and one Written call (one
  // clock read for the run, not one per frame). Returns how many were dropped (counted); the
  // frames that were not are appended to `accepted` when given.
  std::size_t write_each(std::span<const can::Frame> frames,
                         std::vector<can::Frame>* accepted = nullptr);

  // Runs once if the writer's loop ends while not stopped (the bus closed for good, or the loop
  // threw), with why: its owner stops, as for any of its loops (coro::spawn_owned).
  void on_end(std::function<void(const std::string& why)> handler) { on_end_ = std::move(handler); }
  const BusWriteQueue& queue() const { return queue_; }
  // BusWriteQueue::withdraw_single_frames, then the bus's own transmit queue
  // (can::Bus::withdraw_queued); returns how many frames were removed in all.
  std::size_t withdraw(const std::function<bool(const can::Frame&)>& withdrawn);
  // Frames the bus refused although it had reported room (closed meanwhile).
  std::uint64_t refused() const { return refused_; }

 private:
  boost::asio::awaitable<void> run();
  void send(const std::vector<can::Frame>& frames);
  void finish_write(bool was_backlogged);
  void after_change(bool was_backlogged);

  can::Bus& bus_;
  BusWriteQueue queue_;
  Written on_written_;
  BacklogChanged on_backlog_changed_;
  std::function<void(const std::string& why)> on_end_;
  boost::asio::steady_timer wake_;  // condition variable: frames started waiting, or stop()
  std::vector<can::Frame> out_;
  std::uint64_t refused_ = 0;
  bool idle_ = false;  // the coroutine waits on wake_
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
