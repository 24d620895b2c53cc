// A raw CAN socket that only sends, for the bench's frame generators (bus_pacer, pdop_source).
#pragma once

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/socket.h>

#include <cstdio>
#include <cstdlib>
#include <string>

namespace canbridge::bench {

// Opens and binds a CAN_RAW socket on `interface` with an empty receive filter, so it queues
// nothing whatever the bus carries: a generator that also received would spend the CPU it is
// measuring. Exits the process with a message naming `tool` on failure (startup only).
inline int open_send_only_can_socket(const std::string& interface, const char* tool) {
  const int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (fd < 0) {
    std::perror("socket");
    std::exit(1);
  }
  setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, nullptr, 0);
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = static_cast<int>(if_nametoindex(interface.c_str()));
  if (addr.can_ifindex == 0 || bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    std::fprintf(stderr, "%s: cannot bind %s\n", tool, interface.c_str());
    std::exit(1);
  }
  return fd;
}

}  // namespace canbridge::bench
