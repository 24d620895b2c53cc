// The Bus implementation for a real Linux SocketCAN interface (CAN_RAW socket on the event loop).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include "can/bus.hpp"

namespace canbridge::can {

// One CAN_RAW_FILTER entry: a frame passes when (frame id & mask) == (id & mask). Set
// FilterFlags bits in id/mask to match on frame kind as the kernel does (CAN_EFF_FLAG, ...).
struct CanFilter {
  std::uint32_t id = 0;
  std::uint32_t mask = 0;
};

// Raw kernel flag bits, re-exported so filters can be written without <linux/can.h>.
struct FilterFlags {
  static constexpr std::uint32_t extended = 0x80000000U;  // CAN_EFF_FLAG
  static constexpr std::uint32_t remote = 0x40000000U;    // CAN_RTR_FLAG
};

struct SocketCanOptions {
  std::string interface;  // e.g. "vcan0"
  // Kernel receive buffer: absorbs bursts while the loop is busy. Set with SO_RCVBUFFORCE when
  // permitted (CAP_NET_ADMIN), else SO_RCVBUF, which the kernel caps at net.core.rmem_max.
  std::size_t receive_buffer_bytes = 8u << 20;
  std::size_t transmit_queue_frames = 4096;  // send() refuses beyond this
  std::vector<CanFilter> filters;            // empty: every frame
  // CAN_RAW_ERR_FILTER: error classes to receive (CAN_ERR_* bits); they drive state(), never
  // reach the reader. All classes by default; 0 disables error frames.
  std::uint32_t error_mask = 0x1FFFFFFFU;
  std::size_t batch_size = 64;  // frames per recvmmsg, per receive_batch and per writer sendmmsg
};

// Not thread-safe, like the rest of the loop: use it from the executor's one thread.
class SocketCanBus final : public Bus {
 public:
  // Opens, configures and binds the socket and starts the writer. Fails (ec set, nullptr) only
  // for errors a retry would not cure: unknown interface, bad options, no CAN support. An
  // interface that exists but is down is accepted: the bus reopens it once it comes up.
  static std::unique_ptr<SocketCanBus> open(boost::asio::any_io_executor executor,
                                            SocketCanOptions options, std::error_code& ec);
  // Same, throwing std::system_error: for startup code where failure ends the process.
  static std::unique_ptr<SocketCanBus> open(boost::asio::any_io_executor executor,
                                            SocketCanOptions options);

  ~SocketCanBus() override;
  SocketCanBus(const SocketCanBus&) = delete;
  SocketCanBus& operator=(const SocketCanBus&) = delete;

  const std::string& name() const override;
  boost::asio::awaitable<std::error_code> receive_batch(std::vector<Frame>& out) override;
  bool send(const Frame& frame) override;
  // With its transmit queue empty: one non-blocking sendmmsg for the run (up to
  // min(transmit_queue_frames, 1024) frames); the rest, and everything while frames are queued,
  // waits in the queue in order for the writer.
  std::size_t send(std::span<const Frame> frames) override;
  std::size_t send_room() const override;
  std::size_t withdraw_queued(const std::function<bool(const Frame&)>& withdrawn) override;
  boost::asio::awaitable<std::error_code> wait_send_room(std::size_t frames) override;
  BusCounters counters() const override;
  void on_state_change(std::function<void(BusState)> handler) override;
  bool link_up() const override { return interface_up(); }
  // Down: the first read or send that meets ENETDOWN/ENODEV; up: the reopen that succeeds
  // (at once when the rtnetlink watch reports the interface running, else on its backoff).
  void on_link_change(std::function<void(bool up)> handler) override;
  void close() override;

  // Frames accepted by send() and not yet handed to the kernel.
  std::size_t queued() const;
  // False while the interface is lost (down or gone) and the bus is reopening it.
  bool interface_up() const;

 private:
  struct Impl;  // shared with the coroutines the bus runs, so they can outlive this object
  explicit SocketCanBus(std::shared_ptr<Impl> impl);
  std::shared_ptr<Impl> impl_;
};

// The fault-confinement state an error frame announces, or `current` when it announces none
// (protocol errors, lost arbitration, ...). Bus-agnostic: `frame` is an error Frame as any Bus
// would build it (FrameFlags::error, id = CAN_ERR_* class bits, data as the kernel fills it).
BusState state_after_error_frame(const Frame& frame, BusState current);

}  // namespace canbridge::can
