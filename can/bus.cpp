#include "can/bus.hpp"

namespace canbridge::can {

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
