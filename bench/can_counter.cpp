// Benchmark receiver: counts frames of one id on a sink interface, checks loss and order with the
// 64-bit little-endian counter cangen -D i writes, and times them with kernel receive timestamps
// against the same frames seen on a source interface.
//
//   can_counter --source vcan1 --sink vcan0 --id 181 [--sink-id 1a1] --count 100000
//               [--idle-ms 3000] [--trace FILE]
//
// --sink-id: the id the frames carry on the sink (default --id), for a bridge that translates
// COB-IDs (module 1's node 1 TPDO 0x181 is the surface's 0x1A1).
// Prints "ready" once both sockets are bound (start the sender after that), then key=value
// results: delivered, lost, reordered, duplicates, kernel_drops, rate_fps (delivered frames per
// second from the first frame on the source to the last on the sink), latency_us_p50/p99/max
// (sink time minus source time of the same frame).
// --trace FILE: one line per delivered frame, "seq source_ns latency_ns", to see when in a run
// the slow frames were (periodic stalls show a timer, clusters show a batch or a preemption).
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <unordered_map>
#include <vector>

namespace {

struct Options {
  std::string source, sink;
  std::uint32_t id = 0x123;
  std::uint32_t sink_id = 0xFFFFFFFF;  // unset: the same as id
  std::size_t count = 100000;
  int idle_ms = 3000;
  std::string trace;
};

int open_socket(const std::string& name, std::uint32_t id) {
  int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    std::perror("socket");
    std::exit(1);
  }
  int rcvbuf = 256 << 20;  // a whole 100k burst fits: no drop may come from the meter itself
  if (setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &rcvbuf, sizeof rcvbuf) != 0) {
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
  }
  int on = 1;
  setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
  setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on);
  can_filter filter{id, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, &filter, sizeof filter);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(name.c_str()));
  if (addr.can_ifindex == 0 || bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    std::fprintf(stderr, "cannot bind %s\n", name.c_str());
    std::exit(1);
  }
  return fd;
}

struct Rx {
  std::uint64_t seq;
  std::int64_t ns;
};

// Drains every pending frame of fd into out; returns the socket's cumulative drop count.
std::uint32_t drain(int fd, std::vector<Rx>& out) {
  constexpr int kBatch = 256;
  static can_frame frames[kBatch];
  static char control[kBatch][CMSG_SPACE(sizeof(timespec)) + CMSG_SPACE(sizeof(std::uint32_t))];
  static iovec iov[kBatch];
  static mmsghdr msgs[kBatch];
  std::uint32_t drops = 0;
  for (;;) {
    for (int i = 0; i < kBatch; ++i) {
      iov[i] = {&frames[i], sizeof(can_frame)};
      msgs[i].msg_hdr = {};
      msgs[i].msg_hdr.msg_iov = &iov[i];
      msgs[i].msg_hdr.msg_iovlen = 1;
      msgs[i].msg_hdr.msg_control = control[i];
      msgs[i].msg_hdr.msg_controllen = sizeof control[i];
    }
    const int n = recvmmsg(fd, msgs, kBatch, MSG_DONTWAIT, nullptr);
    if (n <= 0) return drops;
    for (int i = 0; i < n; ++i) {
      Rx rx{0, 0};
      std::memcpy(&rx.seq, frames[i].data, 8);
      for (cmsghdr* c = CMSG_FIRSTHDR(&msgs[i].msg_hdr); c; c = CMSG_NXTHDR(&msgs[i].msg_hdr, c)) {
        if (c->cmsg_level != SOL_SOCKET) continue;
        if (c->cmsg_type == SO_TIMESTAMPNS) {
          timespec ts;
          std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
          rx.ns = ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
        } else if (c->cmsg_type == SO_RXQ_OVFL) {
          std::memcpy(&drops, CMSG_DATA(c), sizeof drops);
        }
      }
      out.push_back(rx);
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
    else if (k == "--id")
      o.id = static_cast<std::uint32_t>(std::strtoul(v, nullptr, 16));
    else if (k == "--sink-id")
      o.sink_id = static_cast<std::uint32_t>(std::strtoul(v, nullptr, 16));
    else if (k == "--count")
      o.count = std::strtoul(v, nullptr, 10);
    else if (k == "--idle-ms")
      o.idle_ms = std::atoi(v);
    else if (k == "--trace")
      o.trace = v;
    else {
      std::fprintf(stderr, "unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (o.source.empty() || o.sink.empty()) {
    std::fprintf(stderr, "usage: can_counter --source IF --sink IF --id HEX --count N\n");
    return 2;
  }
  const int src = open_socket(o.source, o.id);
  const int snk = open_socket(o.sink, o.sink_id == 0xFFFFFFFF ? o.id : o.sink_id);
  std::vector<Rx> at_source, at_sink;
  at_source.reserve(o.count);
  at_sink.reserve(o.count);
  std::printf("ready\n");
  std::fflush(stdout);
  std::uint32_t sink_drops = 0, source_drops = 0;
  while (at_sink.size() < o.count) {
    pollfd p[2] = {{src, POLLIN, 0}, {snk, POLLIN, 0}};
    const int r = poll(p, 2, o.idle_ms);
    if (r == 0 && !at_sink.empty()) break;  // nothing more is coming
    if (r == 0) continue;                   // still waiting for the sender to start
    if (p[0].revents & POLLIN) source_drops = std::max(source_drops, drain(src, at_source));
    if (p[1].revents & POLLIN) sink_drops = std::max(sink_drops, drain(snk, at_sink));
  }
  source_drops = std::max(source_drops, drain(src, at_source));

  std::size_t reordered = 0, duplicates = 0;
  std::unordered_map<std::uint64_t, std::int64_t> sent_at;
  sent_at.reserve(at_source.size() * 2);
  for (const Rx& rx : at_source) sent_at.emplace(rx.seq, rx.ns);
  std::vector<bool> seen(o.count + 2, false);
  std::vector<std::int64_t> latency;
  FILE* trace = o.trace.empty() ? nullptr : std::fopen(o.trace.c_str(), "w");
  if (!o.trace.empty() && trace == nullptr) std::perror(o.trace.c_str());
  std::uint64_t prev = 0;
  bool first = true;
  for (const Rx& rx : at_sink) {
    if (!first && rx.seq <= prev) ++reordered;
    first = false;
    prev = rx.seq;
    if (rx.seq < seen.size()) {
      if (seen[rx.seq]) ++duplicates;
      seen[rx.seq] = true;
    }
    if (auto it = sent_at.find(rx.seq); it != sent_at.end()) {
      latency.push_back(rx.ns - it->second);
      if (trace != nullptr) {
        std::fprintf(trace, "%llu %lld %lld\n", static_cast<unsigned long long>(rx.seq),
                     static_cast<long long>(it->second), static_cast<long long>(latency.back()));
      }
    }
  }
  if (trace != nullptr) std::fclose(trace);
  const std::size_t delivered = at_sink.size() - duplicates;
  const std::int64_t t0 = at_source.empty() ? 0 : at_source.front().ns;
  const std::int64_t t1 = at_sink.empty() ? 0 : at_sink.back().ns;
  const double seconds = (t1 - t0) / 1e9;
  std::sort(latency.begin(), latency.end());
  auto pct = [&](double q) {
    return latency.empty() ? 0.0
                           : latency[std::min(latency.size() - 1,
                                              static_cast<std::size_t>(q * latency.size()))] /
                                 1e3;
  };
  std::printf("delivered=%zu\nlost=%zu\nreordered=%zu\nduplicates=%zu\n", delivered,
              o.count > delivered ? o.count - delivered : 0, reordered, duplicates);
  std::printf("kernel_drops_sink=%u\nkernel_drops_source=%u\nsource_frames=%zu\n", sink_drops,
              source_drops, at_source.size());
  std::printf("seconds=%.6f\nrate_fps=%.0f\n", seconds, seconds > 0 ? delivered / seconds : 0.0);
  std::printf("latency_us_p50=%.1f\nlatency_us_p99=%.1f\nlatency_us_max=%.1f\n", pct(0.5),
              pct(0.99), latency.empty() ? 0.0 : latency.back() / 1e3);
  return 0;
}
