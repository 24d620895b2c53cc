// Benchmark receiver for bench/pdop_source: reassembles one node's TPDOP stream (docs/pdop.md
// section 3) on a sink interface, counts the complete and intact packets, and times them with
// kernel receive timestamps against the same packets seen on the source interface.
//
//   pdop_sink --source vcan1 --sink vcan0 --count 2000 [--bytes 256] [--node 1] [--tpdo 1]
//             [--idle-ms 3000] [--start-timeout-ms 60000] [--expect-frames N]
//
// --node is the node id on the sink bus (the surface id when the packets crossed the bridge).
// Prints "ready" once both sockets are bound (start the sender after that). It stops when all
// --count packets have arrived intact, when --expect-frames fragments (default: every fragment of
// --count packets) have arrived, intact or not, when the sink bus has been silent for --idle-ms
// after its first fragment, or when nothing came at all within --start-timeout-ms, and then prints
// key=value lines:
//   delivered    distinct packets complete and intact on the sink (bench/pdop_pattern.hpp check)
//   lost         count - delivered
//   corrupt      complete packets of the wrong length or content (merged, short, damaged)
//   duplicates, reordered (a packet older than the newest one before it)
//   errors_sink  fragments the sink's own reassembler refused (toggle, short, missing first);
//                errors_source the same on the source bus (0 unless the meter itself lost frames)
//   frames_sink, frames_source, kernel_drops_sink, kernel_drops_source
//   seconds      last delivered packet on the sink - first fragment on the source
//   rate_pps     delivered / seconds
//   latency_us_p50/p99/max  last fragment on the sink - last fragment on the source, per packet
//   frame_seconds, frames_per_s  the same for fragments: last fragment on the sink - first on
//                the source, and fragments received on the sink per second (intact or not)
//   first_ns, last_ns, last_frame_ns  those instants (CLOCK_REALTIME, ns)
// The reassembler follows section 3 without its timeout rule: a packet's length and content
// reveal what a timeout would have caught.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/pdop_pattern.hpp"

namespace {

struct Options {
  std::string source, sink;
  std::size_t count = 2000;
  std::size_t bytes = 256;
  unsigned node = 1;
  unsigned tpdo = 1;
  int idle_ms = 3000;
  int start_timeout_ms = 60000;
  std::size_t expect_frames = 0;  // 0: count x fragments of --bytes
};

int open_socket(const std::string& name, std::uint32_t base, unsigned node) {
  const int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    std::perror("socket");
    std::exit(1);
  }
  int rcvbuf = 256 << 20;  // a whole burst fits: no drop may come from the meter itself
  if (setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &rcvbuf, sizeof rcvbuf) != 0) {
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
  }
  int on = 1;
  setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
  setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on);
  // The node's PDO in all four t/c variants: bits 6 and 5 are left out of the mask.
  can_filter filter{base | node, (CAN_SFF_MASK & ~0x60u) | CAN_EFF_FLAG | CAN_RTR_FLAG};
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof filter);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(name.c_str()));
  if (addr.can_ifindex == 0 || bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    std::fprintf(stderr, "pdop_sink: cannot bind %s\n", name.c_str());
    std::exit(1);
  }
  return fd;
}

// One TPDOP stream's receiver (docs/pdop.md section 3, rules 1-4 and 6, with resynchronisation).
class Reassembler {
 public:
  explicit Reassembler(std::size_t max_bytes) : max_bytes_(max_bytes) {}

  // Calls done(bytes, time of the last fragment) for every complete packet.
  template <typename Done>
  void on_frame(const can_frame& f, std::int64_t ns, Done&& done) {
    const bool toggle = (f.can_id & 0x40u) != 0;
    const bool continued = (f.can_id & 0x20u) != 0;
    if (state_ == State::resync) {
      if (!continued) state_ = State::idle;
      return;
    }
    if (state_ == State::idle) {
      if (toggle) return fail(continued);  // first fragment missing
      buffer_.clear();
      expected_toggle_ = false;
      state_ = State::assembling;
    }
    if (toggle != expected_toggle_) return fail(continued);
    if ((continued && f.len < 8) || (!continued && f.len == 0)) return fail(continued);
    buffer_.insert(buffer_.end(), f.data, f.data + f.len);
    if (buffer_.size() > max_bytes_) return fail(continued);
    if (continued) {
      expected_toggle_ = !expected_toggle_;
      return;
    }
    state_ = State::idle;
    done(buffer_, ns);
  }

  std::size_t errors() const { return errors_; }

 private:
  enum class State { idle, assembling, resync };

  void fail(bool continued) {
    ++errors_;
    state_ = continued ? State::resync : State::idle;
  }

  std::size_t max_bytes_;
  State state_ = State::idle;
  bool expected_toggle_ = false;
  std::vector<std::uint8_t> buffer_;
  std::size_t errors_ = 0;
};

// Drains every pending frame of fd into the reassembler; returns the socket's cumulative drop
// count (SO_RXQ_OVFL), adds the frames read to `frames` and keeps the first and the latest
// frame's time.
template <typename Done>
std::uint32_t drain(int fd, Reassembler& r, std::size_t& frames, std::int64_t& first_ns,
                    std::int64_t& latest_ns, Done&& done) {
  constexpr int kBatch = 256;
  static can_frame buf[kBatch];
  static char control[kBatch][CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t))];
  static iovec iov[kBatch];
  static mmsghdr msgs[kBatch];
  std::uint32_t drops = 0;
  for (;;) {
    for (int i = 0; i < kBatch; ++i) {
      iov[i] = {&buf[i], sizeof(can_frame)};
      msgs[i].msg_hdr = {};
      msgs[i].msg_hdr.msg_iov = &iov[i];
      msgs[i].msg_hdr.msg_iovlen = 1;
      msgs[i].msg_hdr.msg_control = control[i];
      msgs[i].msg_hdr.msg_controllen = sizeof control[i];
    }
    const int n = recvmmsg(fd, msgs, kBatch, MSG_DONTWAIT, nullptr);
    if (n <= 0) return drops;
    for (int i = 0; i < n; ++i) {
      std::int64_t ns = 0;
      for (cmsghdr* c = CMSG_FIRSTHDR(&msgs[i].msg_hdr); c; c = CMSG_NXTHDR(&msgs[i].msg_hdr, c)) {
        if (c->cmsg_level != SOL_SOCKET) continue;
        if (c->cmsg_type == SO_TIMESTAMPNS) {
          timespec ts;
          std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
          ns = ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
        } else if (c->cmsg_type == SO_RXQ_OVFL) {
          std::memcpy(&drops, CMSG_DATA(c), sizeof drops);
        }
      }
      if (frames++ == 0) first_ns = ns;
      latest_ns = ns;
      r.on_frame(buf[i], ns, done);
    }
    if (n < kBatch) return drops;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    const char* v = argv[i + 1];
    if (k == "--source")
      o.source = v;
    else if (k == "--sink")
      o.sink = v;
    else if (k == "--count")
      o.count = std::strtoul(v, nullptr, 10);
    else if (k == "--bytes")
      o.bytes = std::strtoul(v, nullptr, 10);
    else if (k == "--node")
      o.node = static_cast<unsigned>(std::strtoul(v, nullptr, 10));
    else if (k == "--tpdo")
      o.tpdo = static_cast<unsigned>(std::strtoul(v, nullptr, 10));
    else if (k == "--idle-ms")
      o.idle_ms = std::atoi(v);
    else if (k == "--start-timeout-ms")
      o.start_timeout_ms = std::atoi(v);
    else if (k == "--expect-frames")
      o.expect_frames = std::strtoul(v, nullptr, 10);
    else {
      std::fprintf(stderr, "pdop_sink: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (o.source.empty() || o.sink.empty() || o.count == 0 || o.bytes < 4 || o.node < 1 ||
      o.node > 31 || o.tpdo < 1 || o.tpdo > 4) {
    std::fprintf(stderr,
                 "usage: pdop_sink --source IF --sink IF --count N [--bytes B] [--node 1..31]"
                 " [--tpdo 1..4] [--idle-ms MS] [--start-timeout-ms MS] [--expect-frames N]\n");
    return 2;
  }
  const std::uint32_t base = 0x180u + 0x100u * (o.tpdo - 1);
  const int src = open_socket(o.source, base, o.node);
  const int snk = open_socket(o.sink, base, o.node);
  Reassembler at_source(o.bytes * 2), at_sink(o.bytes * 2);
  std::vector<std::int64_t> source_ns(o.count, 0), sink_ns(o.count, 0);
  std::size_t frames_source = 0, frames_sink = 0, delivered = 0, corrupt = 0, duplicates = 0,
              reordered = 0;
  std::int64_t first_ns = 0, last_ns = 0, newest = -1;
  std::uint32_t drops_source = 0, drops_sink = 0;

  auto on_source = [&](const std::vector<std::uint8_t>& packet, std::int64_t ns) {
    const std::int64_t index = canbridge::bench::check_packet(packet, o.bytes);
    if (index >= 0 && static_cast<std::size_t>(index) < o.count) source_ns[index] = ns;
  };
  auto on_sink = [&](const std::vector<std::uint8_t>& packet, std::int64_t ns) {
    const std::int64_t index = canbridge::bench::check_packet(packet, o.bytes);
    if (index < 0 || static_cast<std::size_t>(index) >= o.count) {
      ++corrupt;
      return;
    }
    if (sink_ns[index] != 0) {
      ++duplicates;
      return;
    }
    sink_ns[index] = ns;
    ++delivered;
    last_ns = ns;
    if (index < newest) ++reordered;
    newest = std::max(newest, index);
  };
  std::int64_t first_sink_ns = 0, last_source_ns = 0, last_sink_ns = 0;
  auto drain_source = [&] {
    drops_source = std::max(
        drops_source, drain(src, at_source, frames_source, first_ns, last_source_ns, on_source));
  };

  std::printf("ready\n");
  std::fflush(stdout);
  timespec started{};
  clock_gettime(CLOCK_MONOTONIC, &started);
  if (o.expect_frames == 0) o.expect_frames = o.count * ((o.bytes + 7) / 8);
  while (delivered < o.count && frames_sink < o.expect_frames) {
    pollfd p[2] = {{src, POLLIN, 0}, {snk, POLLIN, 0}};
    const int r = poll(p, 2, o.idle_ms);
    if (r == 0 && frames_sink > 0) break;  // the sink bus went quiet: nothing more is coming
    if (r == 0) {
      timespec now{};
      clock_gettime(CLOCK_MONOTONIC, &now);
      if ((now.tv_sec - started.tv_sec) * 1000 > o.start_timeout_ms) break;
      continue;
    }
    // Source first: in the raw path both sockets see each frame at the same instant.
    if (p[0].revents & POLLIN) drain_source();
    if (p[1].revents & POLLIN) {
      drops_sink = std::max(drops_sink,
                            drain(snk, at_sink, frames_sink, first_sink_ns, last_sink_ns, on_sink));
    }
  }
  drain_source();

  std::vector<std::int64_t> latency;
  latency.reserve(delivered);
  for (std::size_t i = 0; i < o.count; ++i) {
    if (sink_ns[i] != 0 && source_ns[i] != 0) latency.push_back(sink_ns[i] - source_ns[i]);
  }
  std::sort(latency.begin(), latency.end());
  auto pct = [&](double q) {
    return latency.empty()
               ? 0.0
               : static_cast<double>(latency[std::min(
                     latency.size() - 1, static_cast<std::size_t>(q * latency.size()))]) /
                     1e3;
  };
  const double seconds = delivered > 0 ? static_cast<double>(last_ns - first_ns) / 1e9 : 0.0;
  std::printf("delivered=%zu\nlost=%zu\ncorrupt=%zu\nduplicates=%zu\nreordered=%zu\n", delivered,
              o.count - delivered, corrupt, duplicates, reordered);
  std::printf("errors_source=%zu\n", at_source.errors());
  std::printf("errors_sink=%zu\nframes_sink=%zu\nframes_source=%zu\n", at_sink.errors(),
              frames_sink, frames_source);
  std::printf("kernel_drops_sink=%u\nkernel_drops_source=%u\n", drops_sink, drops_source);
  std::printf("seconds=%.6f\nrate_pps=%.1f\n", seconds,
              seconds > 0 ? static_cast<double>(delivered) / seconds : 0.0);
  std::printf("latency_us_p50=%.1f\nlatency_us_p99=%.1f\nlatency_us_max=%.1f\n", pct(0.5),
              pct(0.99), latency.empty() ? 0.0 : static_cast<double>(latency.back()) / 1e3);
  const double frame_seconds =
      frames_sink > 0 ? static_cast<double>(last_sink_ns - first_ns) / 1e9 : 0.0;
  std::printf("frame_seconds=%.6f\nframes_per_s=%.1f\n", frame_seconds,
              frame_seconds > 0 ? static_cast<double>(frames_sink) / frame_seconds : 0.0);
  std::printf("first_ns=%lld\nlast_ns=%lld\nlast_frame_ns=%lld\n", static_cast<long long>(first_ns),
              static_cast<long long>(last_ns), static_cast<long long>(last_sink_ns));
  return 0;
}
