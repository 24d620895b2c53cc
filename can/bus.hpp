// The one interface every CAN bus implementation offers to the event loop (SocketCAN, virtual,
// fakes).
#pragma once

#include <boost/asio/awaitable.hpp>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <system_error>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::can {

// ISO 11898 fault confinement states as reported by the controller's error frames.
enum class BusState : std::uint8_t { error_active, error_warning, error_passive, bus_off };
const char* to_string(BusState state);

// Monotonic counters; a frame is never lost without one of these moving.
struct BusCounters {
  std::uint64_t rx_frames = 0;          // frames handed to the reader
  std::uint64_t tx_frames = 0;          // frames accepted by the driver
  std::uint64_t rx_dropped_kernel = 0;  // receive-queue overflows reported by SO_RXQ_OVFL
  std::uint64_t rx_dropped_queue = 0;   // frames dropped because our own receive queue was full
  std::uint64_t tx_dropped_queue = 0;   // send() refused because the transmit queue was full
  std::uint64_t tx_dropped_error = 0;   // frames the driver refused with a hard error
  std::uint64_t tx_retries = 0;         // EAGAIN/ENOBUFS back-offs
  std::uint64_t error_frames = 0;       // error frames received
  std::uint64_t reopens = 0;            // times the interface was lost and reopened
  // While the interface was lost (down or gone, being reopened): send() refused because the
  // transmit queue filled meanwhile (not in tx_dropped_queue), and frames still queued for the
  // old socket that went with it. Frames on the wire meanwhile are not seen at all: the first
  // frame after a reopen carries FrameFlags::follows_loss.
  std::uint64_t tx_dropped_interface_lost = 0;
  std::uint64_t rx_dropped_interface_lost = 0;
  BusState state = BusState::error_active;
};

class Bus {
 public:
  virtual ~Bus() = default;

  virtual const std::string& name() const = 0;

  // Waits until at least one frame is pending, then appends every pending frame (bounded by the
  // implementation's batch size) to `out`, oldest first. Completes with an error once the bus is
  // closed or the wait is cancelled. Error frames are not returned; they update state() and
  // counters(). Only one receive may be outstanding.
  virtual boost::asio::awaitable<std::error_code> receive_batch(std::vector<Frame>& out) = 0;

  // Queues a frame for transmission, strictly in FIFO order, without blocking or suspending.
  // Returns false when the bounded transmit queue is full; the drop is counted.
  virtual bool send(const Frame& frame) = 0;
  // Queues a run of frames, in order, as send(frame) does for each: takes the longest prefix it
  // has room for and returns its length; it stops at the first frame it refuses (counted as
  // send(frame) counts it) and never looks at the frames after it. A bus with a driver of its
  // own hands the run over at once, in one system call where it can; this default sends them
  // one by one.
  virtual std::size_t send(std::span<const Frame> frames) {
    std::size_t taken = 0;
    while (taken < frames.size() && send(frames[taken])) ++taken;
    return taken;
  }
  // How many frames send() takes now without refusing (free transmit-queue slots; the largest
  // size_t for a bus without a bound). For writers of frame sequences that must go whole or not
  // at all (PDO Packet fragments): a sequence with a gap in it can pass as intact.
  virtual std::size_t send_room() const = 0;
  // Removes the frames accepted by send() but not yet handed to the driver for which
  // `withdrawn(frame)` is true (the others keep their order), and returns how many it removed:
  // for a writer whose user was told meanwhile that those frames failed. A bus that queues
  // nothing of its own has nothing to withdraw.
  virtual std::size_t withdraw_queued(const std::function<bool(const Frame&)>& withdrawn) {
    (void)withdrawn;
    return 0;
  }
  // Completes once send_room() >= `frames` (at once if it already is), with an error once the
  // bus is closed or the wait is cancelled. For writers that keep frames waiting upstream while
  // the transmit queue is full: they learn of room without polling. `frames` must not exceed
  // what the idle bus takes (its send_room() before anything was sent), or the wait never ends.
  // Only one wait may be outstanding.
  virtual boost::asio::awaitable<std::error_code> wait_send_room(std::size_t frames) = 0;

  virtual BusCounters counters() const = 0;

  // Called on every fault-confinement state change (from error frames); optional.
  virtual void on_state_change(std::function<void(BusState)> handler) = 0;

  // False while the interface is down or gone (a bus that reopens it says so); true for a bus
  // without an interface of its own.
  virtual bool link_up() const { return true; }
  // Called when the interface is lost (false) and when the bus has it again (true); optional.
  virtual void on_link_change(std::function<void(bool up)> handler) { (void)handler; }

  // Stops both directions; a pending receive_batch completes with operation_aborted.
  virtual void close() = 0;
};

}  // namespace canbridge::can
