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
    if (first(kind)) spdlog::warn(fmt, std::forward<Args>(args)...);
  }
  // The same, once, at info level: a hint about something that is often, not always, a mistake.
  template <typename... Args>
  void hint(std::size_t kind, spdlog::format_string_t<Args...> fmt, Args&&... args) {
    if (first(kind)) spdlog::info(fmt, std::forward<Args>(args)...);
  }

 private:
  // True the first time `kind` is asked about (and never for an unknown kind).
  bool first(std::size_t kind) {
    if (kind >= Kinds || seen_.test(kind)) return false;
    seen_.set(kind);
    return true;
  }

  std::bitset<Kinds> seen_;
};

}  // namespace canbridge::bridge
