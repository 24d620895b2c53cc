// Benchmark SDO client: sends N sequential SDO expedited upload requests to one node and times
// each round trip with kernel receive timestamps on the master's own socket.
//
//   sdo_rtt_probe --interface vcan0 --node 34 [--count 500] [--warmup 10] [--timeout-ms 5000]
//                 [--gap-ms 0] [--objects 1000:00,1018:01,...] [--samples FILE]
//
// The socket receives its own requests (CAN_RAW_RECV_OWN_MSGS), so a request's time is the kernel
// timestamp at which it went onto the bus (when every other socket on the bus sees it) and a
// response's time the kernel timestamp at which it came off the bus: the round trip excludes the
// probe's own scheduling and system calls, as a master's controller timestamps would. The time in
// user space around write() and the matching read() is reported too (wall_us_*).
//
// Requests cycle over several objects (default 1000h:00 and 1018h:01..04) so that a response
// arriving after its request timed out names another object than the request in flight and is
// counted as stale instead of being taken for the current answer; so is any response received
// before the echo of the request in flight. One request is in flight at a
// time; the next goes out as soon as the previous one is answered or timed out (plus --gap-ms).
//
// Prints key=value lines: sent, ok, timeouts, aborts, last_abort, stale, then rtt_us_min, _p50,
// _p90, _p99, _max, _mean over the answered requests, and wall_us_p50 / wall_us_p99. The first
// --warmup requests are sent and awaited but not counted. --samples writes each counted round
// trip (µs) on its own line, for percentiles pooled over several runs.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <numeric>
#include <string>
#include <vector>

namespace {

struct Object {
  std::uint16_t index;
  std::uint8_t sub;
};

struct Options {
  std::string interface;
  unsigned node = 0;
  std::size_t count = 500;
  std::size_t warmup = 10;
  int timeout_ms = 5000;
  int gap_ms = 0;
  std::vector<Object> objects{{0x1000, 0}, {0x1018, 1}, {0x1018, 2}, {0x1018, 3}, {0x1018, 4}};
  std::string samples;
};

constexpr const char* kUsage =
    "usage: sdo_rtt_probe --interface IF --node N [--count 500] [--warmup 10] [--timeout-ms 5000]\n"
    "                     [--gap-ms 0] [--objects IDX:SUB,...] [--samples FILE]\n";

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
}

bool parse_objects(const std::string& text, std::vector<Object>& out) {
  out.clear();
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = std::min(text.find(',', start), text.size());
    const std::string item = text.substr(start, comma - start);
    const std::size_t colon = item.find(':');
    if (colon == std::string::npos) return false;
    char* end = nullptr;
    const unsigned long index = std::strtoul(item.c_str(), &end, 16);
    if (end != item.c_str() + colon || index > 0xFFFF) return false;
    const unsigned long sub = std::strtoul(item.c_str() + colon + 1, &end, 16);
    if (*end != '\0' || sub > 0xFF || colon + 1 == item.size()) return false;
    out.push_back({static_cast<std::uint16_t>(index), static_cast<std::uint8_t>(sub)});
    start = comma + 1;
  }
  return !out.empty();
}

int open_socket(const std::string& name, unsigned node) {
  const int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    std::perror("socket");
    std::exit(1);
  }
  int on = 1;
  setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, &on, sizeof on);
  const can_filter filters[2] = {
      {0x600 + node, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},  // our own requests (echo)
      {0x580 + node, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG},  // the node's responses
  };
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters, sizeof filters);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(name.c_str()));
  if (addr.can_ifindex == 0 || bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    std::fprintf(stderr, "sdo_rtt_probe: cannot bind %s\n", name.c_str());
    std::exit(1);
  }
  return fd;
}

struct Received {
  can_frame frame{};
  std::int64_t kernel_ns = 0;  // SO_TIMESTAMPNS (CLOCK_REALTIME), 0 if absent
  bool own = false;            // our own transmitted frame, looped back (MSG_CONFIRM)
};

// Waits until `deadline` (CLOCK_MONOTONIC ns) for one frame; false on timeout.
bool receive(int fd, std::int64_t deadline, Received& out) {
  for (;;) {
    const std::int64_t left_ns = deadline - monotonic_ns();
    if (left_ns <= 0) return false;
    pollfd p{fd, POLLIN, 0};
    const int r = poll(&p, 1, static_cast<int>((left_ns + 999'999) / 1'000'000));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) {
      std::perror("poll");
      std::exit(1);
    }
    if (r == 0) continue;
    char control[CMSG_SPACE(sizeof(timespec))];
    iovec iov{&out.frame, sizeof out.frame};
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    const ssize_t n = recvmsg(fd, &msg, MSG_DONTWAIT);
    if (n < 0 && (errno == EAGAIN || errno == EINTR)) continue;
    if (n != static_cast<ssize_t>(sizeof(can_frame))) {
      std::perror("recvmsg");
      std::exit(1);
    }
    out.kernel_ns = 0;
    out.own = (msg.msg_flags & MSG_CONFIRM) != 0;
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_TIMESTAMPNS) {
        timespec ts{};
        std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
        out.kernel_ns = ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
      }
    }
    return true;
  }
}

// Nearest-rank percentile of sorted values.
double percentile(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return 0.0;
  const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(sorted.size())));
  return sorted[std::min(sorted.size() - 1, rank == 0 ? 0 : rank - 1)];
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (k == "--help" || k == "-h") {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "sdo_rtt_probe: %s needs a value\n%s", k.c_str(), kUsage);
      return 2;
    }
    const std::string v = argv[++i];
    if (k == "--interface") {
      o.interface = v;
    } else if (k == "--node") {
      o.node = static_cast<unsigned>(std::strtoul(v.c_str(), nullptr, 0));
    } else if (k == "--count") {
      o.count = std::strtoul(v.c_str(), nullptr, 10);
    } else if (k == "--warmup") {
      o.warmup = std::strtoul(v.c_str(), nullptr, 10);
    } else if (k == "--timeout-ms") {
      o.timeout_ms = std::atoi(v.c_str());
    } else if (k == "--gap-ms") {
      o.gap_ms = std::atoi(v.c_str());
    } else if (k == "--objects") {
      if (!parse_objects(v, o.objects)) {
        std::fprintf(stderr, "sdo_rtt_probe: bad --objects '%s' (IDX:SUB,... in hex)\n", v.c_str());
        return 2;
      }
    } else if (k == "--samples") {
      o.samples = v;
    } else {
      std::fprintf(stderr, "sdo_rtt_probe: unknown option %s\n%s", k.c_str(), kUsage);
      return 2;
    }
  }
  if (o.interface.empty() || o.node < 1 || o.node > 127 || o.count == 0 || o.timeout_ms <= 0) {
    std::fputs(kUsage, stderr);
    return 2;
  }

  const int fd = open_socket(o.interface, o.node);
  const canid_t request_id = 0x600 + o.node;
  const canid_t response_id = 0x580 + o.node;
  std::vector<double> rtt_us, wall_us;
  rtt_us.reserve(o.count);
  wall_us.reserve(o.count);
  std::size_t sent = 0, ok = 0, timeouts = 0, aborts = 0, stale = 0, no_timestamp = 0;
  std::uint32_t last_abort = 0;

  for (std::size_t i = 0; i < o.warmup + o.count; ++i) {
    const bool counted = i >= o.warmup;
    const Object& obj = o.objects[i % o.objects.size()];
    can_frame request{};
    request.can_id = request_id;
    request.len = 8;
    request.data[0] = 0x40;  // initiate upload
    request.data[1] = static_cast<std::uint8_t>(obj.index & 0xFF);
    request.data[2] = static_cast<std::uint8_t>(obj.index >> 8);
    request.data[3] = obj.sub;

    const std::int64_t t_write = monotonic_ns();
    if (write(fd, &request, sizeof request) != static_cast<ssize_t>(sizeof request)) {
      std::perror("write");
      return 1;
    }
    if (counted) ++sent;
    const std::int64_t deadline = t_write + o.timeout_ms * 1'000'000LL;
    std::int64_t request_ns = 0;
    bool answered = false;
    Received rx;
    while (!answered && receive(fd, deadline, rx)) {
      const canid_t id = rx.frame.can_id & CAN_SFF_MASK;
      if (id == request_id) {
        // The echo of what we just wrote (its timestamp, or the write's time if it has none).
        if (rx.own) request_ns = rx.kernel_ns != 0 ? rx.kernel_ns : -1;
        continue;
      }
      if (id != response_id || rx.frame.len < 4) continue;
      // Whatever was queued before the echo of this request left the bus before it: not its
      // answer, whatever object it names (a late answer, or a frame the bridge repeated).
      if (request_ns == 0) {
        if (counted) ++stale;
        continue;
      }
      const bool same_object = rx.frame.data[1] == request.data[1] &&
                               rx.frame.data[2] == request.data[2] &&
                               rx.frame.data[3] == request.data[3];
      if (!same_object) {
        if (counted) ++stale;
        continue;
      }
      const std::int64_t t_read = monotonic_ns();
      const std::uint8_t command = rx.frame.data[0];
      if (command == 0x80) {  // abort transfer: the request is answered, without a value
        answered = true;
        if (counted) {
          ++aborts;
          std::memcpy(&last_abort, &rx.frame.data[4], 4);
        }
        continue;
      }
      if ((command & 0xE0) != 0x40) {  // not an upload response: not ours
        if (counted) ++stale;
        continue;
      }
      answered = true;
      if (!counted) continue;
      ++ok;
      const double wall = static_cast<double>(t_read - t_write) / 1e3;
      wall_us.push_back(wall);
      if (request_ns > 0 && rx.kernel_ns != 0) {
        rtt_us.push_back(static_cast<double>(rx.kernel_ns - request_ns) / 1e3);
      } else {
        ++no_timestamp;
        rtt_us.push_back(wall);
      }
    }
    if (!answered && counted) ++timeouts;
    if (o.gap_ms > 0) {
      const timespec gap{o.gap_ms / 1000, (o.gap_ms % 1000) * 1'000'000L};
      nanosleep(&gap, nullptr);
    }
  }
  close(fd);

  if (!o.samples.empty()) {
    if (FILE* f = std::fopen(o.samples.c_str(), "w")) {
      for (double v : rtt_us) std::fprintf(f, "%.1f\n", v);
      std::fclose(f);
    } else {
      std::perror(o.samples.c_str());
    }
  }
  std::vector<double> sorted = rtt_us;
  std::sort(sorted.begin(), sorted.end());
  std::sort(wall_us.begin(), wall_us.end());
  const double mean = sorted.empty() ? 0.0
                                     : std::accumulate(sorted.begin(), sorted.end(), 0.0) /
                                           static_cast<double>(sorted.size());
  std::printf("sent=%zu\nok=%zu\ntimeouts=%zu\naborts=%zu\nlast_abort=%08X\nstale=%zu\n", sent, ok,
              timeouts, aborts, last_abort, stale);
  std::printf("no_timestamp=%zu\n", no_timestamp);
  std::printf("rtt_us_min=%.1f\nrtt_us_p50=%.1f\nrtt_us_p90=%.1f\nrtt_us_p99=%.1f\n",
              sorted.empty() ? 0.0 : sorted.front(), percentile(sorted, 0.5),
              percentile(sorted, 0.9), percentile(sorted, 0.99));
  std::printf("rtt_us_max=%.1f\nrtt_us_mean=%.1f\n", sorted.empty() ? 0.0 : sorted.back(), mean);
  std::printf("wall_us_p50=%.1f\nwall_us_p99=%.1f\n", percentile(wall_us, 0.5),
              percentile(wall_us, 0.99));
  return 0;
}
