// Benchmark sender: one pdop node streaming TPDOP packets (docs/pdop.md section 2) onto a CAN
// interface, as fast as the socket takes them or paced to a packet rate.
//
//   pdop_source --interface vcan1 --count 2000 [--bytes 256] [--node 1] [--tpdo 1] [--rate 0]
//               [--fragment-gap-us 0]
//
// Packet k (0..count-1) carries bench/pdop_pattern.hpp's content, so bench/pdop_sink can check it.
// Each packet's fragments are written back to back, one write() per frame as cangen does; with
// --rate R (packets/s, 0 = unpaced) packet k starts at t0 + k/R on the monotonic clock; with
// --fragment-gap-us G its fragment j is due G x j µs after that, as a CAN bus spaces frames (about
// 130 µs per 8-byte frame at 1 Mbit/s, 260 µs at 500 kbit/s; the guest's timers are coarser). A
// write refused with ENOBUFS (the interface's queue is full) is retried after 100 µs and counted.
// Prints key=value lines when done: packets, frames, enobufs, seconds, start_ns (CLOCK_REALTIME
// of the first write, comparable with the sink's kernel timestamps).
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "bench/pdop_pattern.hpp"
#include "bench/send_only_can_socket.hpp"
#include "canopen/pdop.hpp"

namespace {

struct Options {
  std::string interface;
  std::size_t count = 2000;
  std::size_t bytes = 256;
  unsigned node = 1;
  unsigned tpdo = 1;
  double rate = 0;  // packets/s; 0: as fast as the socket takes them
  long fragment_gap_us = 0;
};

std::int64_t now_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    const char* v = argv[i + 1];
    if (k == "--interface")
      o.interface = v;
    else if (k == "--count")
      o.count = std::strtoul(v, nullptr, 10);
    else if (k == "--bytes")
      o.bytes = std::strtoul(v, nullptr, 10);
    else if (k == "--node")
      o.node = static_cast<unsigned>(std::strtoul(v, nullptr, 10));
    else if (k == "--tpdo")
      o.tpdo = static_cast<unsigned>(std::strtoul(v, nullptr, 10));
    else if (k == "--rate")
      o.rate = std::strtod(v, nullptr);
    else if (k == "--fragment-gap-us")
      o.fragment_gap_us = std::strtol(v, nullptr, 10);
    else {
      std::fprintf(stderr, "pdop_source: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  namespace pdop = canbridge::canopen::pdop;
  const std::uint16_t base = pdop::tpdo_base(o.tpdo);
  if (o.interface.empty() || o.bytes < 4 || o.bytes > pdop::kMaxPacketBytes || base == 0 ||
      o.node < 1 || o.node > pdop::kMaxNode || o.rate < 0 || o.fragment_gap_us < 0) {
    std::fprintf(stderr,
                 "usage: pdop_source --interface IF --count N [--bytes 4..524280] [--node 1..31]"
                 " [--tpdo 1..4] [--rate PACKETS_PER_S] [--fragment-gap-us US]\n");
    return 2;
  }
  const int fd = canbridge::bench::open_send_only_can_socket(o.interface, "pdop_source");

  std::size_t frames = 0, enobufs = 0;
  const std::int64_t start_real = now_ns(CLOCK_REALTIME);
  const std::int64_t start = now_ns(CLOCK_MONOTONIC);
  const auto sleep_until = [](std::int64_t due) {
    const timespec at{static_cast<time_t>(due / 1'000'000'000LL),
                      static_cast<long>(due % 1'000'000'000LL)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, nullptr) == EINTR) {
    }
  };
  for (std::size_t k = 0; k < o.count; ++k) {
    std::int64_t packet_start = now_ns(CLOCK_MONOTONIC);
    if (o.rate > 0) {
      packet_start = start + static_cast<std::int64_t>(1e9 * static_cast<double>(k) / o.rate);
      sleep_until(packet_start);
    }
    const auto packet = canbridge::bench::make_packet(static_cast<std::uint32_t>(k), o.bytes);
    std::int64_t j = 0;
    for (const canbridge::can::Frame& f :
         pdop::fragment(base, static_cast<canbridge::canopen::NodeId>(o.node), packet)) {
      if (o.fragment_gap_us > 0 && j > 0) sleep_until(packet_start + j * o.fragment_gap_us * 1000);
      ++j;
      can_frame cf{};
      cf.can_id = f.id;
      cf.len = f.len;
      std::memcpy(cf.data, f.data.data(), f.len);
      for (;;) {
        if (write(fd, &cf, sizeof cf) == static_cast<ssize_t>(sizeof cf)) break;
        if (errno == ENOBUFS) {
          ++enobufs;
          const timespec pause{0, 100'000};
          nanosleep(&pause, nullptr);
        } else if (errno != EINTR) {
          std::perror("pdop_source: write");
          return 1;
        }
      }
      ++frames;
    }
  }
  const double seconds = static_cast<double>(now_ns(CLOCK_MONOTONIC) - start) / 1e9;
  std::printf("packets=%zu\nframes=%zu\nenobufs=%zu\nseconds=%.6f\nstart_ns=%lld\n", o.count,
              frames, enobufs, seconds, static_cast<long long>(start_real));
  close(fd);
  return 0;
}
