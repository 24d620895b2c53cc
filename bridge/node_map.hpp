// Which module owns which surface node id, and how each module's local node ids map to it.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "bridge/canopen/cob_id.hpp"

namespace canbridge::bridge {

using ModuleId = std::uint32_t;
using canopen::NodeId;

// Nodes per module bus with the default mapping (seed 000: at most 31 nodes per local bus).
inline constexpr NodeId kDefaultNodesPerModule = 31;
inline constexpr ModuleId kMaxDefaultModuleId = 3;  // 4 x 32 surface ids fit in 1..127

struct NodeOwner {
  std::size_t module_index;  // position in NodeMap::modules()
  NodeId local;
};

// One module's table. Index 0 of each array is unused (node id 0 is "all nodes" in NMT).
struct ModuleNodes {
  ModuleId id = 0;
  std::array<NodeId, 128> local_to_surface{};  // 0 = not mapped
};

class NodeMap {
 public:
  // Default mapping of the foundation: surface = local + 32 x module id for local 1..31.
  static std::vector<std::pair<NodeId, NodeId>> default_pairs(ModuleId module);

  // Adds a module with explicit (local, surface) pairs. Returns the problems found (empty if the
  // module was added): ids out of 1..127, a local or surface id used twice, a surface id already
  // owned by another module (naming it), a duplicate module id.
  std::vector<std::string> add_module(ModuleId id,
                                      const std::vector<std::pair<NodeId, NodeId>>& pairs);

  const std::vector<ModuleNodes>& modules() const { return modules_; }
  std::optional<std::size_t> index_of(ModuleId id) const;

  std::optional<NodeOwner> owner_of_surface(NodeId surface) const {
    if (surface == 0 || surface > canopen::kMaxNodeId) return std::nullopt;
    const Owner& o = surface_owner_[surface];
    if (o.local == 0) return std::nullopt;
    return NodeOwner{o.module_index, o.local};
  }
  NodeId surface_of(std::size_t module_index, NodeId local) const {
    return local <= canopen::kMaxNodeId ? modules_[module_index].local_to_surface[local] : 0;
  }

 private:
  struct Owner {
    std::size_t module_index = 0;
    NodeId local = 0;  // 0 = unowned
  };
  std::vector<ModuleNodes> modules_;
  std::array<Owner, 128> surface_owner_{};
};

}  // namespace canbridge::bridge
