#include "can/frame.hpp"

#include <cstdio>

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

}  // namespace canbridge::can
