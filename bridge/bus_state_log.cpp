#include "bridge/bus_state_log.hpp"

#include <spdlog/spdlog.h>

#include <memory>

namespace canbridge::bridge {

std::string link_change_text(bool up) {
  return up ? "up" : "down";
}

std::string state_change_text(can::BusState previous, can::BusState next) {
  if (previous == can::BusState::bus_off && next == can::BusState::error_active) {
    return "restarted (error-active)";
  }
  return can::to_string(next);
}

void log_bus_state_changes(can::Bus& bus, const std::string& who) {
  bus.on_link_change([who](bool up) {
    const auto level = up ? spdlog::level::info : spdlog::level::warn;
    spdlog::log(level, "{}: {}", who, link_change_text(up));
  });
  auto last = std::make_shared<can::BusState>(bus.counters().state);
  bus.on_state_change([who, last](can::BusState next) {
    const can::BusState previous = *last;
    *last = next;
    spdlog::level::level_enum level = spdlog::level::warn;
    if (next == can::BusState::bus_off) level = spdlog::level::err;
    if (next == can::BusState::error_active) level = spdlog::level::info;
    spdlog::log(level, "{}: {}", who, state_change_text(previous, next));
  });
  if (!bus.link_up()) spdlog::warn("{}: {}", who, link_change_text(false));
}

}  // namespace canbridge::bridge
