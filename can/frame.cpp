#include "can/frame.hpp"

#include <cstdio>

#include "can/bus.hpp"

namespace canbridge::can {

std::string to_string(const Frame& frame) {
  char buf[64];
  int n = frame.is_extended() ? std::snprintf(buf, sizeof buf, "%08X#", frame.id)
                              : std::snprintf(buf, sizeof buf, "%03X#", frame.id);
  std::string s(buf, static_cast<std::size_t>(n));
  if (frame.is_remote()) {
    s += 'R';
    if (frame.len != 0) s += static_cast<char>('0' + frame.len);
    return s;
  }
  for (std::uint8_t i = 0; i < frame.len; ++i) {
    std::snprintf(buf, sizeof buf, "%02X", frame.data[i]);
    s += buf;
  }
  return s;
}

const char* to_string(BusState state) {
  switch (state) {
    case BusState::error_active:
      return "error-active";
    case BusState::error_warning:
      return "error-warning";
    case BusState::error_passive:
      return "error-passive";
    case BusState::bus_off:
      return "bus-off";
  }
  return "unknown";
}

}  // namespace canbridge::can
