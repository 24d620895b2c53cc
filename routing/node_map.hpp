// Which module owns which surface node id, and how each module's local node ids map to it.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "canopen/cob_id.hpp"
#include "routing/id_profile.hpp"

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

inline constexpr std::size_t kStandardCobIds = 0x800;

// Who owns a surface COB-ID: the module, the COB-ID on its bus, and what it is there.
struct CobOwner {
  std::size_t module_index = 0;
  std::uint16_t local_cob = 0;  // 0 = unowned (COB-ID 0 is NMT, never node-addressed)
  NodeId local = 0;
  const ProfileCobId* what = nullptr;  // points into profile_cob_ids(), which lives forever
};

// One module's table. Index 0 of each array is unused (node id 0 is "all nodes" in NMT).
struct ModuleNodes {
  ModuleId id = 0;
  IdProfile profile = IdProfile::cia301;
  std::array<NodeId, 128> local_to_surface{};  // 0 = not mapped
  // Local COB-ID -> surface COB-ID, 0 = not owned: the module's whole image, so translating
  // a frame is one lookup whatever the profile.
  std::vector<std::uint16_t> local_to_surface_cob = std::vector<std::uint16_t>(kStandardCobIds);
  // A surface id a node takes when the boot-up that confirms its node-id command comes
  // (plan_move); 0 = none.
  std::array<NodeId, 128> planned_surface{};
};

class NodeMap {
 public:
  // Default mapping of the foundation: surface = local + 32 x module id for local 1..31.
  static std::vector<std::pair<NodeId, NodeId>> default_pairs(ModuleId module);

  // Adds a module with explicit (local, surface) pairs. Returns the problems found (empty if the
  // module was added): ids out of 1..127 (1..31 for pdop and qd, local and surface), a local or
  // surface id used twice, a surface id already owned by another module (naming it), a
  // duplicate module id, and any surface COB-ID of this module's image that another module's
  // image holds already (naming both owners and the COB-ID).
  std::vector<std::string> add_module(ModuleId id,
                                      const std::vector<std::pair<NodeId, NodeId>>& pairs,
                                      IdProfile profile = IdProfile::cia301);

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
  // The surface COB-ID of a frame on module_index's bus; 0 if the module's image lacks it.
  std::uint16_t surface_cob_of(std::size_t module_index, std::uint32_t local_cob) const {
    return local_cob < kStandardCobIds ? modules_[module_index].local_to_surface_cob[local_cob]
                                       : std::uint16_t{0};
  }
  // The owner of a surface COB-ID, nullopt if no module's image holds it.
  std::optional<CobOwner> owner_of_surface_cob(std::uint32_t surface_cob) const {
    if (surface_cob >= kStandardCobIds || surface_cob_owner_[surface_cob].local_cob == 0) {
      return std::nullopt;
    }
    return surface_cob_owner_[surface_cob];
  }
  // "module 1 (qd) local node 5 -> surface 5 TPDO2": one owner, for problem messages.
  std::string describe(const CobOwner& owner) const;

  // The live map: a node renamed by the fpga node-id command (docs/nmt-node-id.md) moves.
  // Why local node `from` of the module cannot become local `to` with surface id `surface`
  // (nullopt: it can): an id outside 1..127 or the profile's range, `to` mapped to another
  // surface id, `surface` owned by a node other than `from` (naming it), or a COB-ID of the new
  // image held by another node's image (naming the owner). `from` 0: a node the map has no pair
  // for.
  std::optional<std::string> move_problem(std::size_t module_index, NodeId from, NodeId to,
                                          NodeId surface) const;
  // Unmaps `from` (its surface id and COB-IDs become free) and maps `to` to `surface`; false
  // (nothing changed) when move_problem() names a problem.
  bool move(std::size_t module_index, NodeId from, NodeId to, NodeId surface);
  // `local` takes `surface` when a boot-up confirms the node-id command sent to it; a later
  // plan replaces it. The gateway applies it (rename_follower.hpp).
  void plan_move(std::size_t module_index, NodeId local, NodeId surface) {
    modules_[module_index].planned_surface[local] = surface;
  }
  NodeId planned_move(std::size_t module_index, NodeId local) const {
    return local <= canopen::kMaxNodeId ? modules_[module_index].planned_surface[local] : NodeId{0};
  }
  void cancel_move(std::size_t module_index, NodeId local) {
    if (local <= canopen::kMaxNodeId) modules_[module_index].planned_surface[local] = 0;
  }

 private:
  struct Owner {
    std::size_t module_index = 0;
    NodeId local = 0;  // 0 = unowned
  };
  std::vector<ModuleNodes> modules_;
  std::array<Owner, 128> surface_owner_{};
  std::vector<CobOwner> surface_cob_owner_ = std::vector<CobOwner>(kStandardCobIds);
};

}  // namespace canbridge::bridge
