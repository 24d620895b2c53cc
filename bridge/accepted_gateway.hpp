// A gateway the surface accepts, from its configuration: the identity it must prove and the
// modules and surface node ids it may serve. The surface binds no one else.
#pragma once

#include <string>
#include <vector>

#include "routing/node_map.hpp"

namespace canbridge::bridge {

struct AcceptedGateway {
  std::string name;
  std::vector<ModuleId> modules;
  // Empty: the default mapping of its modules (NodeMap::default_pairs).
  std::vector<NodeId> surface_nodes;
};

}  // namespace canbridge::bridge
