#include "bridge/node_map.hpp"

#include <algorithm>

namespace canbridge::bridge {

std::vector<std::pair<NodeId, NodeId>> NodeMap::default_pairs(ModuleId module) {
  std::vector<std::pair<NodeId, NodeId>> pairs;
  if (module > kMaxDefaultModuleId) return pairs;
  for (NodeId local = 1; local <= kDefaultNodesPerModule; ++local) {
    pairs.emplace_back(local, static_cast<NodeId>(local + 32 * module));
  }
  return pairs;
}

std::optional<std::size_t> NodeMap::index_of(ModuleId id) const {
  auto it = std::find_if(modules_.begin(), modules_.end(),
                         [id](const ModuleNodes& m) { return m.id == id; });
  if (it == modules_.end()) return std::nullopt;
  return static_cast<std::size_t>(it - modules_.begin());
}

std::vector<std::string> NodeMap::add_module(ModuleId id,
                                             const std::vector<std::pair<NodeId, NodeId>>& pairs) {
  std::vector<std::string> problems;
  if (index_of(id)) problems.push_back("module id " + std::to_string(id) + " is used twice");
  ModuleNodes module;
  module.id = id;
  std::array<bool, 128> surface_seen{};
  for (auto [local, surface] : pairs) {
    const std::string where = "module " + std::to_string(id) + " node " + std::to_string(local);
    if (local == 0 || local > canopen::kMaxNodeId) {
      problems.push_back(where + ": local node id must be 1..127");
      continue;
    }
    if (surface == 0 || surface > canopen::kMaxNodeId) {
      problems.push_back(where + ": surface node id " + std::to_string(surface) +
                         " must be 1..127");
      continue;
    }
    if (module.local_to_surface[local] != 0) {
      problems.push_back(where + ": local node id mapped twice");
    }
    if (surface_seen[surface]) {
      problems.push_back(where + ": surface node id " + std::to_string(surface) +
                         " is given to two nodes of this module");
    }
    const Owner& other = surface_owner_[surface];
    if (other.local != 0) {
      problems.push_back(
          where + ": surface node id " + std::to_string(surface) + " is already owned by module " +
          std::to_string(modules_[other.module_index].id) + " node " + std::to_string(other.local));
    }
    surface_seen[surface] = true;
    module.local_to_surface[local] = surface;
  }
  if (!problems.empty()) return problems;
  const std::size_t index = modules_.size();
  for (NodeId local = 1; local <= canopen::kMaxNodeId; ++local) {
    if (NodeId surface = module.local_to_surface[local]; surface != 0) {
      surface_owner_[surface] = Owner{index, local};
    }
  }
  modules_.push_back(module);
  return problems;
}

}  // namespace canbridge::bridge
