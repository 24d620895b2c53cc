#include "bridge/demo.hpp"

namespace canbridge::bridge {
int run_demo(const DemoOptions&) {
  return 1;
}
}  // namespace canbridge::bridge
