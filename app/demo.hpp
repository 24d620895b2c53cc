// The embedded default job: gateway and surface in one process on virtual buses and a loopback
// TCP backbone, with simulated CANopen nodes, showing a person that the tunnel works.
#pragma once

namespace canbridge::bridge {

struct DemoOptions {
  unsigned modules = 2;           // module ids 0..modules-1, each its own virtual bus
  unsigned nodes_per_module = 4;  // local node ids 1..n: one node of each sim kind
};

// Returns 0 when every node was seen and every SDO read through the tunnel succeeded.
int run_demo(const DemoOptions& options);

}  // namespace canbridge::bridge
