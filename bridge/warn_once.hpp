// Logs the first occurrence of each kind of problem at warn level and stays quiet after, so a
// flood of bad input costs a counter increment instead of a log line per frame.
#pragma once

#include <spdlog/spdlog.h>

#include <bitset>
#include <cstddef>
#include <utility>

namespace canbridge::bridge {

template <std::size_t Kinds>
class WarnOnce {
 public:
  template <typename... Args>
  void warn(std::size_t kind, spdlog::format_string_t<Args...> fmt, Args&&... args) {
    if (kind >= Kinds || seen_.test(kind)) return;
    seen_.set(kind);
    spdlog::warn(fmt, std::forward<Args>(args)...);
  }
  // The same, once, at info level: a hint about something that is often, not always, a mistake.
  template <typename... Args>
  void hint(std::size_t kind, spdlog::format_string_t<Args...> fmt, Args&&... args) {
    if (kind >= Kinds || seen_.test(kind)) return;
    seen_.set(kind);
    spdlog::info(fmt, std::forward<Args>(args)...);
  }

 private:
  std::bitset<Kinds> seen_;
};

}  // namespace canbridge::bridge
