// Benchmark sender: a paced stream of counter frames on one or more buses, a fixed number of
// frames per bus per tick, each tick's frames of one bus handed to the kernel with one sendmmsg.
//
//   bus_pacer --interfaces vcan1[,vcan2...] --id 181 [--per-tick 8] [--tick-us 1000]
//             (--count N | --seconds S)
//
// Each bus gets its own 64-bit little-endian counter from 0 in all 8 data bytes, as cangen -D i
// writes them, so bench/can_counter checks loss and order per bus. Ticks are absolute
// (clock_nanosleep TIMER_ABSTIME); a wake that comes after later ticks sends their frames too
// (one sendmmsg per bus), so the average rate holds on a coarse timer and the batches grow
// instead. Prints key=value lines at the end: frames_per_bus, wakes, late_wakes (wakes that
// carried more than one tick), largest_batch, seconds, rate_fps_per_bus.
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/send_only_can_socket.hpp"

namespace {

struct Options {
  std::vector<std::string> interfaces;
  std::uint32_t id = 0x181;
  unsigned per_tick = 8;
  long tick_us = 1000;
  std::uint64_t count = 0;
  double seconds = 0;
};

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
}

// Sends frames[0..n) with as few sendmmsg calls as the kernel allows (blocking socket).
void send_all(int fd, can_frame* frames, unsigned n) {
  std::vector<iovec> iov(n);
  std::vector<mmsghdr> msgs(n);
  for (unsigned i = 0; i < n; ++i) {
    iov[i] = {&frames[i], sizeof(can_frame)};
    msgs[i] = {};
    msgs[i].msg_hdr.msg_iov = &iov[i];
    msgs[i].msg_hdr.msg_iovlen = 1;
  }
  unsigned done = 0;
  while (done < n) {
    const int r = sendmmsg(fd, msgs.data() + done, n - done, 0);
    if (r < 0) {
      if (errno == EINTR) continue;
      if (errno == ENOBUFS || errno == EAGAIN) {
        usleep(100);  // the interface's queue is full: the frame waits, it is never dropped
        continue;
      }
      std::perror("sendmmsg");
      std::exit(1);
    }
    done += static_cast<unsigned>(r);
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    const char* v = argv[i + 1];
    if (k == "--interfaces") {
      std::string list = v;
      for (std::size_t start = 0;;) {
        const auto comma = list.find(',', start);
        o.interfaces.push_back(list.substr(start, comma - start));
        if (comma == std::string::npos) break;
        start = comma + 1;
      }
    } else if (k == "--id") {
      o.id = static_cast<std::uint32_t>(std::strtoul(v, nullptr, 16));
    } else if (k == "--per-tick") {
      o.per_tick = static_cast<unsigned>(std::strtoul(v, nullptr, 10));
    } else if (k == "--tick-us") {
      o.tick_us = std::strtol(v, nullptr, 10);
    } else if (k == "--count") {
      o.count = std::strtoull(v, nullptr, 10);
    } else if (k == "--seconds") {
      o.seconds = std::strtod(v, nullptr);
    } else {
      std::fprintf(stderr, "bus_pacer: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (o.interfaces.empty() || o.per_tick == 0 || o.tick_us <= 0 ||
      (o.count == 0 && o.seconds <= 0)) {
    std::fprintf(stderr,
                 "usage: bus_pacer --interfaces IF[,IF...] --id HEX [--per-tick N] "
                 "[--tick-us U] (--count N | --seconds S)\n");
    return 2;
  }
  std::vector<int> fds;
  for (const auto& name : o.interfaces)
    fds.push_back(canbridge::bench::open_send_only_can_socket(name, "bus_pacer"));
  std::vector<can_frame> frames;
  std::uint64_t sent = 0, wakes = 0, late_wakes = 0, largest = 0;
  const std::int64_t tick_ns = o.tick_us * 1000;
  const std::int64_t t0 = now_ns();
  const std::int64_t end = o.seconds > 0 ? t0 + static_cast<std::int64_t>(o.seconds * 1e9) : 0;
  std::int64_t next = t0;
  for (;;) {
    if (o.count != 0 && sent >= o.count) break;
    if (end != 0 && next >= end) break;
    timespec at{static_cast<time_t>(next / 1'000'000'000), static_cast<long>(next % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, nullptr) == EINTR) {
    }
    // Every tick elapsed since the start owes its frames: a wake that comes late (the guest's
    // timer is coarse) sends the missed ticks' frames too, so the average rate holds.
    const auto due_ticks = static_cast<std::uint64_t>((now_ns() - t0) / tick_ns) + 1;
    std::uint64_t due = due_ticks * o.per_tick;
    if (o.count != 0) due = std::min(due, o.count);
    const auto n = static_cast<unsigned>(due - sent);
    if (n > o.per_tick) ++late_wakes;
    largest = std::max<std::uint64_t>(largest, n);
    frames.assign(n, can_frame{});
    for (unsigned i = 0; i < n; ++i) {
      frames[i].can_id = o.id;
      frames[i].len = 8;
      const std::uint64_t seq = sent + i;
      std::memcpy(frames[i].data, &seq, 8);
    }
    // The same counter values on every bus: each bus is its own stream.
    for (int fd : fds) send_all(fd, frames.data(), n);
    sent += n;
    ++wakes;
    next = t0 + static_cast<std::int64_t>(due_ticks) * tick_ns;
  }
  const double seconds = static_cast<double>(now_ns() - t0) / 1e9;
  std::printf(
      "frames_per_bus=%llu\nwakes=%llu\nlate_wakes=%llu\nlargest_batch=%llu\nseconds=%.3f\n",
      static_cast<unsigned long long>(sent), static_cast<unsigned long long>(wakes),
      static_cast<unsigned long long>(late_wakes), static_cast<unsigned long long>(largest),
      seconds);
  std::printf("rate_fps_per_bus=%.0f\n", seconds > 0 ? static_cast<double>(sent) / seconds : 0.0);
  return 0;
}
