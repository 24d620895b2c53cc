#include "can/socketcan_bus.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/posix/stream_descriptor.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <system_error>

#include "can/link_watch.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::can {

namespace asio = boost::asio;
using namespace std::chrono_literals;

namespace {

constexpr auto kTxBackoffMin = std::chrono::microseconds(100);
constexpr auto kTxBackoffMax = std::chrono::microseconds(10'000);
constexpr auto kReopenBackoffMin = std::chrono::milliseconds(100);
constexpr auto kReopenBackoffMax = std::chrono::milliseconds(2000);
constexpr std::size_t kMaxBatch = 1024;  // UIO_MAXIOV: the kernel's limit for vlen
// What one queued classic frame costs a CAN_RAW socket's send buffer (the skb's truesize, a
// little under 1 KiB on 64-bit kernels; the default 208 KiB buffer holds ~200 frames). The
// kernel doubles the value set, which leaves room for its own bookkeeping.
constexpr std::size_t kSendBufferBytesPerFrame = 1024;

// Room for SCM_TIMESTAMPNS (struct timespec) and SO_RXQ_OVFL (u32), each with its cmsghdr.
constexpr std::size_t cmsg_align(std::size_t n) {
  return (n + sizeof(std::size_t) - 1) & ~(sizeof(std::size_t) - 1);
}
constexpr std::size_t kControlBytes = cmsg_align(sizeof(cmsghdr)) + cmsg_align(sizeof(timespec)) +
                                      cmsg_align(sizeof(cmsghdr)) +
                                      cmsg_align(sizeof(std::uint32_t));
struct alignas(cmsghdr) ControlBuffer {
  unsigned char bytes[kControlBytes];
};

std::error_code errno_code(int err) {
  return {err, std::system_category()};
}

// Errors after which the socket is useless until the interface is back: reopen it.
bool interface_lost(int err) {
  return err == ENETDOWN || err == ENODEV || err == ENXIO || err == EBADF;
}

void to_kernel(const Frame& f, can_frame& cf) {
  std::memset(&cf, 0, sizeof cf);
  if (f.is_error()) {
    cf.can_id = CAN_ERR_FLAG | (f.id & CAN_ERR_MASK);
  } else if (f.is_extended()) {
    cf.can_id = CAN_EFF_FLAG | (f.id & CAN_EFF_MASK);
  } else {
    cf.can_id = f.id & CAN_SFF_MASK;
  }
  if (f.is_remote()) cf.can_id |= CAN_RTR_FLAG;
  cf.len = std::min<std::uint8_t>(f.len, CAN_MAX_DLEN);
  if (!f.is_remote()) std::memcpy(cf.data, f.data.data(), cf.len);
}

void from_kernel(const can_frame& cf, Frame& f) {
  f = Frame{};
  if (cf.can_id & CAN_ERR_FLAG) {
    f.flags = FrameFlags::error;
    f.id = cf.can_id & CAN_ERR_MASK;
  } else if (cf.can_id & CAN_EFF_FLAG) {
    f.flags = FrameFlags::extended;
    f.id = cf.can_id & CAN_EFF_MASK;
  } else {
    f.id = cf.can_id & CAN_SFF_MASK;
  }
  if (cf.can_id & CAN_RTR_FLAG) f.flags |= FrameFlags::remote;
  f.len = std::min<std::uint8_t>(cf.len, CAN_MAX_DLEN);
  if (!f.is_remote()) std::memcpy(f.data.data(), cf.data, f.len);
}

// A bounded FIFO whose storage grows with the deepest backlog it has held, up to its capacity:
// a transmit queue sized for bursts (8,192 frames in the samples) costs no resident memory on a
// bus that never backs up, and it is not given back, so a bus that did back up once does not
// allocate again on the hot path.
class FrameRing {
 public:
  explicit FrameRing(std::size_t capacity) : capacity_(capacity) {}
  bool full() const { return size_ == capacity_; }
  bool empty() const { return size_ == 0; }
  std::size_t size() const { return size_; }
  const Frame& at(std::size_t i) const { return slots_[(head_ + i) % slots_.size()]; }
  void push_back(const Frame& f) {
    if (size_ == slots_.size()) grow();
    slots_[(head_ + size_) % slots_.size()] = f;
    ++size_;
  }
  void pop_front(std::size_t n) {
    if (n == 0) return;
    head_ = (head_ + n) % slots_.size();
    size_ -= n;
  }
  void clear() { head_ = size_ = 0; }
  // Keeps, in order, the frames `drop` says no to; returns how many it dropped.
  template <typename Drop>
  std::size_t remove_if(Drop&& drop) {
    std::size_t kept = 0;
    for (std::size_t i = 0; i < size_; ++i) {
      const Frame f = at(i);
      if (!drop(f)) slots_[(head_ + kept++) % slots_.size()] = f;
    }
    const std::size_t removed = size_ - kept;
    size_ = kept;
    return removed;
  }

 private:
  // Doubles the storage (from 64 slots), the frames kept in order from the front.
  void grow() {
    const std::size_t slots = std::min(capacity_, std::max<std::size_t>(64, slots_.size() * 2));
    std::vector<Frame> bigger(slots);
    for (std::size_t i = 0; i < size_; ++i) bigger[i] = at(i);
    slots_ = std::move(bigger);
    head_ = 0;
  }

  std::size_t capacity_;
  std::vector<Frame> slots_;
  std::size_t head_ = 0;
  std::size_t size_ = 0;
};

int set_int_option(int fd, int level, int name, int value) {
  return ::setsockopt(fd, level, name, &value, sizeof value);
}

}  // namespace

struct SocketCanBus::Impl : std::enable_shared_from_this<Impl> {
  Impl(asio::any_io_executor ex, SocketCanOptions opts)
      : executor(ex),
        options(std::move(opts)),
        socket(ex),
        reader_wake(ex),
        writer_wake(ex),
        room_wake(ex),
        writer_backoff(ex),
        reopen_timer(ex),
        link_watch(ex),
        tx_queue(options.transmit_queue_frames),
        rx_msgs(options.batch_size),
        rx_iov(options.batch_size),
        rx_frames(options.batch_size),
        rx_control(options.batch_size),
        tx_msgs(direct_batch()),
        tx_iov(direct_batch()),
        tx_frames(direct_batch()) {
    // The wake timers are condition variables: they never expire, cancel() is notify_all. Their
    // expiry is set once here; resetting it per wait would cancel the other waiter.
    reader_wake.expires_at(asio::steady_timer::time_point::max());
    writer_wake.expires_at(asio::steady_timer::time_point::max());
    room_wake.expires_at(asio::steady_timer::time_point::max());
    // The message headers point at member buffers once; only lengths are reset per call.
    for (std::size_t i = 0; i < options.batch_size; ++i) {
      rx_iov[i] = {&rx_frames[i], sizeof(can_frame)};
      rx_msgs[i] = {};
      rx_msgs[i].msg_hdr.msg_iov = &rx_iov[i];
      rx_msgs[i].msg_hdr.msg_iovlen = 1;
      rx_msgs[i].msg_hdr.msg_control = rx_control[i].bytes;
    }
    for (std::size_t i = 0; i < tx_msgs.size(); ++i) {
      tx_iov[i] = {&tx_frames[i], sizeof(can_frame)};
      tx_msgs[i] = {};
      tx_msgs[i].msg_hdr.msg_iov = &tx_iov[i];
      tx_msgs[i].msg_hdr.msg_iovlen = 1;
    }
  }

  // Creates, configures and binds a fresh socket. ENETDOWN: the interface exists but is down.
  std::error_code open_socket() {
    const unsigned index = ::if_nametoindex(options.interface.c_str());
    if (index == 0) return errno_code(ENODEV);
    const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
    if (fd < 0) return errno_code(errno);
    auto fail = [fd](int err) {
      ::close(fd);
      return errno_code(err);
    };
    const int rcvbuf =
        static_cast<int>(std::min<std::size_t>(options.receive_buffer_bytes, std::size_t{1} << 30));
    // SO_RCVBUFFORCE ignores net.core.rmem_max but needs CAP_NET_ADMIN; SO_RCVBUF is capped.
    if (set_int_option(fd, SOL_SOCKET, SO_RCVBUFFORCE, rcvbuf) != 0 &&
        set_int_option(fd, SOL_SOCKET, SO_RCVBUF, rcvbuf) != 0) {
      return fail(errno);
    }
    // The send buffer bounds how many frames one sendmmsg hands over (the default holds ~200):
    // room for the whole transmit queue, so a batch send is not cut short by it. Forced when
    // permitted; else capped by net.core.wmem_max, which only means shorter sendmmsg runs.
    const int sndbuf = static_cast<int>(std::min<std::size_t>(
        options.transmit_queue_frames * kSendBufferBytesPerFrame, std::size_t{1} << 30));
    if (set_int_option(fd, SOL_SOCKET, SO_SNDBUFFORCE, sndbuf) != 0 &&
        set_int_option(fd, SOL_SOCKET, SO_SNDBUF, sndbuf) != 0) {
      return fail(errno);
    }
    if (set_int_option(fd, SOL_SOCKET, SO_TIMESTAMPNS, 1) != 0) return fail(errno);
    if (set_int_option(fd, SOL_SOCKET, SO_RXQ_OVFL, 1) != 0) return fail(errno);
    // Loop protection: the bridge must never read back what it wrote, while other sockets on
    // the interface (candump, the local CANopen stack) must see it. Both are kernel defaults;
    // set them anyway so no system-wide change can flip them.
    if (set_int_option(fd, SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, 0) != 0) return fail(errno);
    if (set_int_option(fd, SOL_CAN_RAW, CAN_RAW_LOOPBACK, 1) != 0) return fail(errno);
    if (!options.filters.empty()) {
      std::vector<can_filter> filters;
      filters.reserve(options.filters.size());
      for (const CanFilter& f : options.filters) filters.push_back({f.id, f.mask});
      if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                       static_cast<socklen_t>(filters.size() * sizeof(can_filter))) != 0) {
        return fail(errno);
      }
    }
    const can_err_mask_t err_mask = options.error_mask & CAN_ERR_MASK;
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &err_mask, sizeof err_mask) != 0) {
      return fail(errno);
    }
    sockaddr_can addr{};
    addr.can_family = AF_CAN;
    addr.can_ifindex = static_cast<int>(index);
    if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) return fail(errno);
    // Binding to a down interface succeeds and leaves ENETDOWN pending: treat it as not open.
    int pending = 0;
    socklen_t pending_len = sizeof pending;
    if (::getsockopt(fd, SOL_SOCKET, SO_ERROR, &pending, &pending_len) != 0) return fail(errno);
    if (pending != 0) return fail(pending);

    boost::system::error_code ec;
    socket.assign(fd, ec);
    if (ec) return fail(ec.value());
    last_overflow = 0;   // SO_RXQ_OVFL counts per socket
    rx_drained = false;  // a fresh socket: read before the first wait
    return {};
  }

  // The socket failed with an interface-level error: close it (which aborts the reader's and
  // writer's waits) and reopen in the background. Queued frames stay queued.
  void lose_socket() {
    if (socket.is_open()) {
      count_frames_left_behind();
      boost::system::error_code ignored;
      socket.close(ignored);
      if (link_handler && !closed) link_handler(false);
    }
    if (closed || reopening) return;
    reopening = true;
    coro::spawn_owned(executor, reopen(shared_from_this()),
                      [self = shared_from_this()](const std::string& why) {
                        if (!why.empty()) self->fail("reopen loop", why);
                      });
  }

  // One of the bus's own loops threw: without it the bus would look open and never move a frame
  // again. Close it and end the pending receive with an error, so the role sees it and stops.
  void fail(const char* loop, const std::string& why) {
    if (closed) return;
    spdlog::error("bus {}: {} stopped: {}; closing the bus", options.interface, loop,
                  why.empty() ? "it ended" : why);
    failed = true;
    close();
  }

  // Frames the kernel queued for a socket about to be closed go with it: count them. The loss
  // itself is reported once (a pending socket error) before the queue reads again. Bounded: on
  // an interface still up (an error other than a loss), frames keep coming.
  void count_frames_left_behind() {
    bool error_seen = false;
    for (int round = 0; round < 64; ++round) {
      for (std::size_t i = 0; i < options.batch_size; ++i) {
        rx_msgs[i].msg_hdr.msg_controllen = sizeof(ControlBuffer);
        rx_msgs[i].msg_hdr.msg_flags = 0;
      }
      const int n = ::recvmmsg(socket.native_handle(), rx_msgs.data(),
                               static_cast<unsigned>(options.batch_size), MSG_DONTWAIT, nullptr);
      if (n < 0 && interface_lost(errno) && !error_seen) {
        error_seen = true;
        continue;
      }
      if (n <= 0) return;
      for (int i = 0; i < n; ++i) {
        const auto k = static_cast<std::size_t>(i);
        if (rx_msgs[k].msg_len == sizeof(can_frame) && !(rx_frames[k].can_id & CAN_ERR_FLAG)) {
          ++counters.rx_dropped_interface_lost;
        }
      }
    }
  }

  // While the bus reopens: the kernel's link notifications end the backoff wait as soon as the
  // interface is running again. Without netlink (not permitted, not built) the backoff alone.
  void start_link_watch() {
    std::error_code ec;
    if (!link_watch.open(ec)) {
      spdlog::debug("bus {}: no rtnetlink link watch ({}); reopening on a timer", options.interface,
                    ec.message());
      return;
    }
    // Its end is never fatal (the backoff still reopens), but an operator should see why the
    // quick reopen stopped working.
    coro::spawn_owned(executor, watch_link(shared_from_this()),
                      [name = options.interface](const std::string& why) {
                        if (!why.empty()) {
                          spdlog::warn("bus {}: link watch ended ({}); reopening on a timer", name,
                                       why);
                        }
                      });
  }

  static asio::awaitable<void> watch_link(std::shared_ptr<Impl> self) {
    std::vector<LinkEvent> events;
    while (!self->closed && self->link_watch.is_open()) {
      if (co_await self->link_watch.next(events)) break;
      // The index is looked up per event: an interface removed and created again has a new one.
      const unsigned index = ::if_nametoindex(self->options.interface.c_str());
      for (const LinkEvent& e : events) {
        if (e.up && e.ifindex == index) {
          self->link_came_up = true;
          self->reopen_timer.cancel();
        }
      }
    }
  }

  static asio::awaitable<void> reopen(std::shared_ptr<Impl> self) {
    self->start_link_watch();
    // First attempt at once: a quick down/up flap may already be over.
    auto delay = std::chrono::milliseconds(0);
    while (!self->closed) {
      if (delay.count() != 0 && !self->link_came_up) {
        self->reopen_timer.expires_after(delay);
        co_await self->reopen_timer.async_wait(asio::as_tuple(asio::use_awaitable));
        if (self->closed) break;
      }
      if (!self->open_socket()) {
        ++self->counters.reopens;
        // The bus went on while this socket was away: whoever reads must not take the next
        // frame for the one after the last it saw (a PDO Packet with a hole in it).
        self->loss_pending = true;
        self->reader_wake.cancel();
        self->writer_wake.cancel();
        if (self->link_handler) self->link_handler(true);
        break;
      }
      self->link_came_up = false;
      delay = std::clamp(delay * 2, kReopenBackoffMin, kReopenBackoffMax);
    }
    self->link_came_up = false;
    self->link_watch.close();
    self->reopening = false;
  }

  asio::awaitable<std::error_code> receive(std::vector<Frame>& out) {
    auto cancelled = [](const asio::cancellation_state& state) {
      return state.cancelled() != asio::cancellation_type::none;
    };
    const auto canceled = std::make_error_code(std::errc::operation_canceled);
    const auto failure = std::make_error_code(std::errc::io_error);
    // A reader on a saturated bus could read batch after batch without ever suspending and
    // starve the rest of the loop: after a full batch, give the loop one turn first. Otherwise
    // go straight on; a turn costs an extra epoll_wait and a frame's worth of latency.
    if (rx_batch_was_full) co_await asio::post(executor, asio::use_awaitable);
    for (;;) {
      if (failed) co_return failure;
      if (closed || cancelled(co_await asio::this_coro::cancellation_state)) co_return canceled;
      if (!socket.is_open()) {
        co_await reader_wake.async_wait(asio::as_tuple(asio::use_awaitable));
        continue;
      }
      if (rx_drained) {
        // The last recvmmsg emptied the kernel queue, so reading again now would most likely
        // return EAGAIN: wait first. asio's registration is edge-triggered, but async_wait
        // re-arms it with EPOLL_CTL_MOD, and the kernel's ep_modify re-polls the socket and
        // queues it as ready if frames arrived since that read: none is left without a wakeup.
        rx_drained = false;
        co_await socket.async_wait(asio::posix::stream_descriptor::wait_read,
                                   asio::as_tuple(asio::use_awaitable));
        continue;  // closed, cancelled or lost meanwhile: checked above
      }
      // Otherwise read before waiting: frames that arrived while no wait was pending produced
      // their edge already (a fresh socket, a full last batch, an interrupted wait).
      const int err = receive_once(out);
      if (err == 0) co_return std::error_code{};
      if (err == EAGAIN || err == EWOULDBLOCK) {
        co_await socket.async_wait(asio::posix::stream_descriptor::wait_read,
                                   asio::as_tuple(asio::use_awaitable));
      } else if (err == -1) {
        // Only error frames this round: look again (after a wait if the queue was drained, else
        // after giving the loop a turn).
        if (!rx_drained) co_await asio::post(executor, asio::use_awaitable);
      } else if (interface_lost(err)) {
        // The kernel reports the loss once; what it queued for this socket before it is still
        // readable: deliver that (one batch; anything beyond is counted), then reopen. A
        // transient loss reaches the caller only as counters.
        const int rest = receive_once(out);
        lose_socket();
        if (rest == 0) co_return std::error_code{};
      } else if (err != EINTR) {
        lose_socket();
      }
    }
  }

  // One recvmmsg. 0: frames were appended; -1: only error frames; else the errno.
  int receive_once(std::vector<Frame>& out) {
    const std::size_t batch = options.batch_size;
    for (std::size_t i = 0; i < batch; ++i) {
      rx_msgs[i].msg_hdr.msg_controllen = sizeof(ControlBuffer);
      rx_msgs[i].msg_hdr.msg_flags = 0;
    }
    const int n = ::recvmmsg(socket.native_handle(), rx_msgs.data(), static_cast<unsigned>(batch),
                             MSG_DONTWAIT, nullptr);
    if (n < 0) {
      rx_drained = rx_batch_was_full = false;
      return errno;
    }
    // Fewer messages than asked for: the kernel queue was empty when recvmmsg returned, so the
    // next receive waits for readiness instead of reading first (see receive()).
    rx_batch_was_full = static_cast<std::size_t>(n) == batch;
    rx_drained = !rx_batch_was_full;
    std::size_t delivered = 0;
    for (int i = 0; i < n; ++i) {
      msghdr& hdr = rx_msgs[static_cast<std::size_t>(i)].msg_hdr;
      std::chrono::nanoseconds stamp{0};
      for (cmsghdr* c = CMSG_FIRSTHDR(&hdr); c != nullptr; c = CMSG_NXTHDR(&hdr, c)) {
        if (c->cmsg_level != SOL_SOCKET) continue;
        if (c->cmsg_type == SCM_TIMESTAMPNS) {
          timespec ts;
          std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
          stamp = std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec);
        } else if (c->cmsg_type == SO_RXQ_OVFL) {
          std::uint32_t drops = 0;
          std::memcpy(&drops, CMSG_DATA(c), sizeof drops);
          // The kernel's count is cumulative per socket and wraps at 2^32: add the difference.
          const auto lost = static_cast<std::uint32_t>(drops - last_overflow);
          counters.rx_dropped_kernel += lost;
          last_overflow = drops;
          // The count travels with the first frame queued after the drops: it follows the gap.
          if (lost != 0) loss_pending = true;
        }
      }
      // CAN FD frames never reach a socket without CAN_RAW_FD_FRAMES; anything not a classic
      // frame is ignored.
      if (rx_msgs[static_cast<std::size_t>(i)].msg_len != sizeof(can_frame)) continue;
      const can_frame& cf = rx_frames[static_cast<std::size_t>(i)];
      if (cf.can_id & CAN_ERR_FLAG) {
        on_error_frame(cf);
        continue;
      }
      Frame& f = out.emplace_back();
      from_kernel(cf, f);
      f.timestamp = stamp;
      if (loss_pending) f.flags |= FrameFlags::follows_loss;
      loss_pending = false;
      ++delivered;
    }
    counters.rx_frames += delivered;
    return delivered > 0 ? 0 : -1;
  }

  void on_error_frame(const can_frame& cf) {
    ++counters.error_frames;
    Frame f;
    from_kernel(cf, f);
    const BusState next = state_after_error_frame(f, counters.state);
    if (next == counters.state) return;
    counters.state = next;
    if (state_handler) state_handler(next);
  }

  bool send(const Frame& frame) {
    if (closed) {
      ++counters.tx_dropped_error;
      return false;
    }
    if (tx_queue.full()) {
      // Why it is full matters to whoever reads the counters: a bus too slow for the load, or
      // an interface away (down, gone) while the queue kept taking frames.
      ++(socket.is_open() ? counters.tx_dropped_queue : counters.tx_dropped_interface_lost);
      return false;
    }
    tx_queue.push_back(frame);
    if (writer_idle) {
      writer_idle = false;
      writer_wake.cancel();
    }
    return true;
  }

  // With nothing queued, the run goes to the kernel at once in one non-blocking sendmmsg (up to
  // direct_batch() frames); what the kernel does not take now is queued behind it for the
  // writer, so order holds. Any error is left for the writer, which meets it on its next pass.
  std::size_t send_batch(std::span<const Frame> frames) {
    std::size_t taken = 0;
    if (!closed && tx_queue.empty() && socket.is_open() && !frames.empty()) {
      const std::size_t n = std::min(frames.size(), tx_msgs.size());
      for (std::size_t i = 0; i < n; ++i) to_kernel(frames[i], tx_frames[i]);
      const int sent = ::sendmmsg(socket.native_handle(), tx_msgs.data(), static_cast<unsigned>(n),
                                  MSG_DONTWAIT);
      if (sent > 0) {
        taken = static_cast<std::size_t>(sent);
        counters.tx_frames += taken;
      }
    }
    while (taken < frames.size() && send(frames[taken])) ++taken;
    return taken;
  }

  // The largest run one sendmmsg carries: a whole transmit queue, within the kernel's limit.
  std::size_t direct_batch() const {
    return std::max(options.batch_size, std::min(options.transmit_queue_frames, kMaxBatch));
  }

  static asio::awaitable<void> writer(std::shared_ptr<Impl> self) {
    Impl& s = *self;
    auto backoff = kTxBackoffMin;
    while (!s.closed) {
      if (s.tx_queue.empty() || !s.socket.is_open()) {
        s.writer_idle = true;
        co_await s.writer_wake.async_wait(asio::as_tuple(asio::use_awaitable));
        s.writer_idle = false;
        continue;
      }
      const std::size_t n = std::min(s.tx_queue.size(), s.options.batch_size);
      for (std::size_t i = 0; i < n; ++i) to_kernel(s.tx_queue.at(i), s.tx_frames[i]);
      const int sent = ::sendmmsg(s.socket.native_handle(), s.tx_msgs.data(),
                                  static_cast<unsigned>(n), MSG_DONTWAIT);
      if (sent > 0) {
        // Only the head leaves the queue, so order is kept whatever happens to the rest.
        s.tx_queue.pop_front(static_cast<std::size_t>(sent));
        s.counters.tx_frames += static_cast<std::uint64_t>(sent);
        s.notify_room();
        backoff = kTxBackoffMin;
        // Let the loop breathe between batches of a long queue.
        if (!s.tx_queue.empty()) co_await asio::post(s.executor, asio::use_awaitable);
        continue;
      }
      const int err = sent < 0 ? errno : EAGAIN;
      if (err == EINTR) continue;
      if (err == EAGAIN || err == EWOULDBLOCK) {
        // The socket's send buffer is full: writable again once the driver frees skbs.
        ++s.counters.tx_retries;
        co_await s.socket.async_wait(asio::posix::stream_descriptor::wait_write,
                                     asio::as_tuple(asio::use_awaitable));
      } else if (err == ENOBUFS) {
        // The device queue is full; nothing to poll for, so back off on a timer.
        ++s.counters.tx_retries;
        s.writer_backoff.expires_after(backoff);
        co_await s.writer_backoff.async_wait(asio::as_tuple(asio::use_awaitable));
        backoff = std::min(backoff * 2, kTxBackoffMax);
      } else if (interface_lost(err)) {
        s.lose_socket();
      } else {
        // The kernel refused the head frame itself (EINVAL, EPERM, ...): retrying cannot help.
        s.tx_queue.pop_front(1);
        ++s.counters.tx_dropped_error;
        s.notify_room();
      }
    }
  }

  std::size_t room() const {
    if (closed || tx_queue.size() >= tx_capacity()) return 0;
    return tx_capacity() - tx_queue.size();
  }

  // The writer freed slots: wake a writer upstream once as many as it waits for are free.
  void notify_room() {
    if (room_wanted != 0 && room() >= room_wanted) room_wake.cancel();
  }

  asio::awaitable<std::error_code> wait_room(std::size_t frames) {
    const auto canceled = std::make_error_code(std::errc::operation_canceled);
    while (!closed && room() < frames) {
      room_wanted = frames;
      co_await room_wake.async_wait(asio::as_tuple(asio::use_awaitable));
      room_wanted = 0;
      // The timer is a condition variable: cancel() means "room" (or "closed"). A cancellation
      // requested by our caller must still end the wait.
      auto state = co_await asio::this_coro::cancellation_state;
      if (state.cancelled() != asio::cancellation_type::none) co_return canceled;
    }
    if (closed) co_return canceled;
    co_return std::error_code{};
  }

  void close() {
    if (closed) return;
    closed = true;
    counters.tx_dropped_error += tx_queue.size();
    tx_queue.clear();
    boost::system::error_code ignored;
    socket.close(ignored);
    reader_wake.cancel();
    writer_wake.cancel();
    room_wake.cancel();
    writer_backoff.cancel();
    reopen_timer.cancel();
    link_watch.close();
  }

  asio::any_io_executor executor;
  SocketCanOptions options;
  asio::posix::stream_descriptor socket;  // closed while the interface is lost
  asio::steady_timer reader_wake;         // notified when the socket is reopened or closed
  asio::steady_timer writer_wake;         // notified on send(), reopen and close
  asio::steady_timer room_wake;           // notified when room_wanted slots are free, and close
  asio::steady_timer writer_backoff;
  asio::steady_timer reopen_timer;
  LinkWatch link_watch;       // open while reopening
  bool link_came_up = false;  // the watch saw the interface running: retry without waiting
  FrameRing tx_queue;
  std::size_t tx_capacity() const { return options.transmit_queue_frames; }
  BusCounters counters;
  std::function<void(BusState)> state_handler;
  std::function<void(bool)> link_handler;
  std::uint32_t last_overflow = 0;
  bool loss_pending = false;  // frames were lost: flag the next frame delivered
  bool closed = false;
  bool failed = false;  // closed because one of its own loops failed (see fail())
  bool reopening = false;
  bool writer_idle = false;
  std::size_t room_wanted = 0;     // free slots a wait_send_room() waits for; 0: none waits
  bool rx_drained = false;         // the last recvmmsg returned fewer frames than asked for
  bool rx_batch_was_full = false;  // the last recvmmsg filled the whole batch

  // Per-batch system call buffers, allocated once: no allocation per frame.
  std::vector<mmsghdr> rx_msgs;
  std::vector<iovec> rx_iov;
  std::vector<can_frame> rx_frames;
  std::vector<ControlBuffer> rx_control;
  std::vector<mmsghdr> tx_msgs;
  std::vector<iovec> tx_iov;
  std::vector<can_frame> tx_frames;
};

std::unique_ptr<SocketCanBus> SocketCanBus::open(asio::any_io_executor executor,
                                                 SocketCanOptions options, std::error_code& ec) {
  ec.clear();
  if (options.interface.empty() || options.interface.size() >= IFNAMSIZ ||
      options.batch_size == 0 || options.batch_size > kMaxBatch ||
      options.transmit_queue_frames == 0) {
    ec = std::make_error_code(std::errc::invalid_argument);
    return nullptr;
  }
  auto impl = std::make_shared<Impl>(executor, std::move(options));
  const std::error_code opened = impl->open_socket();
  if (opened && opened.value() != ENETDOWN) {
    ec = opened;
    return nullptr;
  }
  coro::spawn_owned(executor, Impl::writer(impl), [impl](const std::string& why) {
    if (!impl->closed) impl->fail("transmit loop", why);
  });
  if (opened) impl->lose_socket();  // down at startup: open it once it comes up
  return std::unique_ptr<SocketCanBus>(new SocketCanBus(std::move(impl)));
}

std::unique_ptr<SocketCanBus> SocketCanBus::open(asio::any_io_executor executor,
                                                 SocketCanOptions options) {
  std::error_code ec;
  std::string interface = options.interface;
  auto bus = open(std::move(executor), std::move(options), ec);
  if (!bus) throw std::system_error(ec, "cannot open CAN interface '" + interface + "'");
  return bus;
}

SocketCanBus::SocketCanBus(std::shared_ptr<Impl> impl) : impl_(std::move(impl)) {}

SocketCanBus::~SocketCanBus() {
  impl_->close();
}

const std::string& SocketCanBus::name() const {
  return impl_->options.interface;
}

asio::awaitable<std::error_code> SocketCanBus::receive_batch(std::vector<Frame>& out) {
  auto impl = impl_;  // the bus may be destroyed while this waits
  co_return co_await impl->receive(out);
}

bool SocketCanBus::send(const Frame& frame) {
  return impl_->send(frame);
}

std::size_t SocketCanBus::send(std::span<const Frame> frames) {
  return impl_->send_batch(frames);
}

std::size_t SocketCanBus::send_room() const {
  return impl_->room();
}

asio::awaitable<std::error_code> SocketCanBus::wait_send_room(std::size_t frames) {
  auto impl = impl_;  // the bus may be destroyed while this waits
  co_return co_await impl->wait_room(frames);
}

BusCounters SocketCanBus::counters() const {
  return impl_->counters;
}

void SocketCanBus::on_state_change(std::function<void(BusState)> handler) {
  impl_->state_handler = std::move(handler);
}

void SocketCanBus::on_link_change(std::function<void(bool up)> handler) {
  impl_->link_handler = std::move(handler);
}

void SocketCanBus::close() {
  impl_->close();
}

// The writer takes frames from the head of the queue on each pass and holds none across a wait,
// so the queue may be filtered between passes.
std::size_t SocketCanBus::withdraw_queued(const std::function<bool(const Frame&)>& withdrawn) {
  return impl_->tx_queue.remove_if(withdrawn);
}

std::size_t SocketCanBus::queued() const {
  return impl_->tx_queue.size();
}

bool SocketCanBus::interface_up() const {
  return impl_->socket.is_open();
}

BusState state_after_error_frame(const Frame& frame, BusState current) {
  if (!frame.is_error()) return current;
  if (frame.id & CAN_ERR_BUSOFF) return BusState::bus_off;
  if (frame.id & CAN_ERR_RESTARTED) return BusState::error_active;
  if (frame.id & CAN_ERR_CRTL) {
    const std::uint8_t ctrl = frame.data[1];
    if (ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)) return BusState::error_passive;
    if (ctrl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING)) return BusState::error_warning;
    if (ctrl & CAN_ERR_CRTL_ACTIVE) return BusState::error_active;
  }
  return current;
}

}  // namespace canbridge::can
