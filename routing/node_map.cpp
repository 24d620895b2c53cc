#include "routing/node_map.hpp"

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

namespace {

std::string owner_text(ModuleId module, IdProfile profile, NodeId local, NodeId surface,
                       const ProfileCobId& what) {
  return "module " + std::to_string(module) + " (" + to_string(profile) + ") local node " +
         std::to_string(local) + " -> surface " + std::to_string(surface) + " " + what.name;
}

std::string hex_cob(std::uint16_t cob) {
  static constexpr char kDigits[] = "0123456789ABCDEF";
  std::string s = "0x";
  for (int shift = 8; shift >= 0; shift -= 4) s += kDigits[(cob >> shift) & 0xF];
  return s;
}

// Why a pdop/qd node id must stay within 1..31, in the words of the profile.
const char* five_bit_reason(IdProfile profile) {
  return profile == IdProfile::pdop
             ? "a pdop bus keeps the node id in bits 4-0 (bits 6-5 are the PDO Packet toggle "
               "and continued bits)"
             : "a qd bus keeps the node id in bits 4-0 (bits 6-5 select the node's slot)";
}

}  // namespace

std::string NodeMap::describe(const CobOwner& owner) const {
  const ModuleNodes& m = modules_[owner.module_index];
  return owner_text(m.id, m.profile, owner.local, m.local_to_surface[owner.local], *owner.what);
}

std::vector<std::string> NodeMap::add_module(ModuleId id,
                                             const std::vector<std::pair<NodeId, NodeId>>& pairs,
                                             IdProfile profile) {
  std::vector<std::string> problems;
  if (index_of(id)) problems.push_back("module id " + std::to_string(id) + " is used twice");
  ModuleNodes module;
  module.id = id;
  module.profile = profile;
  const NodeId max = max_node_id(profile);
  std::array<bool, 128> surface_seen{};
  std::vector<std::pair<NodeId, NodeId>> valid;  // nodes whose image is checked below
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
    if (local > max) {
      problems.push_back(where + " (" + to_string(profile) +
                         "): local node id must be 1..31: " + five_bit_reason(profile));
      continue;
    }
    if (surface > max) {
      // The surface COB-ID is function | bits 6-5 | surface id: a surface id above 31 would
      // spill into bits 6-5 and fold two local COB-IDs onto one.
      problems.push_back(where + " (" + to_string(profile) + "): surface node id " +
                         std::to_string(surface) + " must be 1..31: " + five_bit_reason(profile) +
                         " and the surface id replaces it");
      continue;
    }
    bool ok = true;
    if (module.local_to_surface[local] != 0) {
      problems.push_back(where + ": local node id mapped twice");
      ok = false;
    }
    if (surface_seen[surface]) {
      problems.push_back(where + ": surface node id " + std::to_string(surface) +
                         " is given to two nodes of this module");
      ok = false;
    }
    const Owner& other = surface_owner_[surface];
    if (other.local != 0) {
      problems.push_back(
          where + ": surface node id " + std::to_string(surface) + " is already owned by module " +
          std::to_string(modules_[other.module_index].id) + " node " + std::to_string(other.local));
      ok = false;
    }
    surface_seen[surface] = true;
    module.local_to_surface[local] = surface;
    if (ok) valid.emplace_back(local, surface);
  }
  // The image: every surface COB-ID this module's nodes own, against every earlier module's.
  // One problem per colliding module (the first COB-ID and how many), not one per COB-ID.
  const std::size_t index = modules_.size();
  std::vector<CobOwner> image;
  std::vector<std::size_t> collisions(modules_.size(), 0);
  std::vector<std::string> first(modules_.size());
  for (auto [local, surface] : valid) {
    for (const ProfileCobId& what : profile_cob_ids(profile)) {
      const auto surface_cob = static_cast<std::uint16_t>(what.base + surface);
      const CobOwner& other = surface_cob_owner_[surface_cob];
      if (other.local_cob != 0) {
        if (collisions[other.module_index]++ == 0) {
          first[other.module_index] = "COB-ID " + hex_cob(surface_cob) + ": " +
                                      owner_text(id, profile, local, surface, what) +
                                      " collides with " + describe(other);
        }
        continue;
      }
      module.local_to_surface_cob[what.base + local] = surface_cob;
      image.push_back(CobOwner{index, static_cast<std::uint16_t>(what.base + local), local, &what});
    }
  }
  for (std::size_t m = 0; m < collisions.size(); ++m) {
    if (collisions[m] == 0) continue;
    problems.push_back(first[m] + (collisions[m] > 1 ? " (" + std::to_string(collisions[m]) +
                                                           " COB-IDs collide in all)"
                                                     : std::string()));
  }
  if (!problems.empty()) return problems;
  for (NodeId local = 1; local <= canopen::kMaxNodeId; ++local) {
    if (NodeId surface = module.local_to_surface[local]; surface != 0) {
      surface_owner_[surface] = Owner{index, local};
    }
  }
  for (const CobOwner& owner : image) {
    surface_cob_owner_[module.local_to_surface_cob[owner.local_cob]] = owner;
  }
  modules_.push_back(std::move(module));
  return problems;
}

std::optional<std::string> NodeMap::move_problem(std::size_t module_index, NodeId from, NodeId to,
                                                 NodeId surface) const {
  if (module_index >= modules_.size()) return "no module " + std::to_string(module_index);
  const ModuleNodes& m = modules_[module_index];
  const NodeId max = max_node_id(m.profile);
  const std::string where = "module " + std::to_string(m.id) + " (" + to_string(m.profile) + ")";
  if (to == 0 || to > max) {
    return where + ": local node id " + std::to_string(to) + " is outside 1.." +
           std::to_string(max);
  }
  if (surface == 0 || surface > max) {
    return where + ": surface node id " + std::to_string(surface) + " is outside 1.." +
           std::to_string(max) +
           (m.profile == IdProfile::cia301 ? std::string()
                                           : std::string(": ") + five_bit_reason(m.profile));
  }
  if (to != from && m.local_to_surface[to] != 0) {
    return where + ": local node id " + std::to_string(to) + " is mapped to surface " +
           std::to_string(m.local_to_surface[to]);
  }
  const auto is_from = [&](std::size_t module, NodeId local) {
    return from != 0 && module == module_index && local == from;
  };
  const Owner& other = surface_owner_[surface];
  if (other.local != 0 && !is_from(other.module_index, other.local)) {
    return "surface node id " + std::to_string(surface) + " is already owned by module " +
           std::to_string(modules_[other.module_index].id) + " node " + std::to_string(other.local);
  }
  for (const ProfileCobId& what : profile_cob_ids(m.profile)) {
    const auto surface_cob = static_cast<std::uint16_t>(what.base + surface);
    const CobOwner& holder = surface_cob_owner_[surface_cob];
    if (holder.local_cob != 0 && !is_from(holder.module_index, holder.local)) {
      return "COB-ID " + hex_cob(surface_cob) + ": " +
             owner_text(m.id, m.profile, to, surface, what) + " collides with " + describe(holder);
    }
  }
  return std::nullopt;
}

bool NodeMap::move(std::size_t module_index, NodeId from, NodeId to, NodeId surface) {
  if (move_problem(module_index, from, to, surface)) return false;
  ModuleNodes& m = modules_[module_index];
  const auto& image = profile_cob_ids(m.profile);
  if (from != 0 && m.local_to_surface[from] != 0) {
    const NodeId old = m.local_to_surface[from];
    surface_owner_[old] = Owner{};
    for (const ProfileCobId& what : image) {
      const auto old_cob = static_cast<std::uint16_t>(what.base + old);
      if (surface_cob_owner_[old_cob].module_index == module_index &&
          surface_cob_owner_[old_cob].local == from) {
        surface_cob_owner_[old_cob] = CobOwner{};
      }
      m.local_to_surface_cob[what.base + from] = 0;
    }
    m.local_to_surface[from] = 0;
  }
  m.local_to_surface[to] = surface;
  surface_owner_[surface] = Owner{module_index, to};
  for (const ProfileCobId& what : image) {
    const auto surface_cob = static_cast<std::uint16_t>(what.base + surface);
    m.local_to_surface_cob[what.base + to] = surface_cob;
    surface_cob_owner_[surface_cob] =
        CobOwner{module_index, static_cast<std::uint16_t>(what.base + to), to, &what};
  }
  return true;
}

}  // namespace canbridge::bridge
