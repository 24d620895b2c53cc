#include "bridge/gateway_table.hpp"

#include <algorithm>
#include <cstdio>

#include "canopen/cob_id.hpp"

namespace canbridge::bridge {

namespace {

std::string quoted(std::string_view name) {
  return "gateway '" + std::string(name) + "'";
}

std::string hex_cob(std::uint32_t cob) {
  char text[8];
  std::snprintf(text, sizeof text, "0x%03X", static_cast<unsigned>(cob));
  return text;
}

// The module of `claims` that claims surface node `node` / COB-ID `cob` (0 when none does).
ModuleId module_with_node(const GatewayClaims& claims, NodeId node) {
  for (const ModuleClaim& m : claims.modules) {
    if (std::find(m.surface_nodes.begin(), m.surface_nodes.end(), node) != m.surface_nodes.end())
      return m.id;
  }
  return 0;
}
ModuleId module_with_cob(const GatewayClaims& claims, std::uint32_t cob) {
  for (const ModuleClaim& m : claims.modules) {
    for (const CobRange& r : m.cob_ranges) {
      if (cob >= r.first && cob <= r.last) return m.id;
    }
  }
  return 0;
}

}  // namespace

GatewayTable::GatewayTable(std::string surface_name) : surface_name_(std::move(surface_name)) {
  node_owner_.fill(kNobody);
  cob_owner_.fill(kNobody);
}

std::optional<GatewayTable::GatewayId> GatewayTable::find(std::string_view name) const {
  for (std::size_t i = 0; i < entries_.size(); ++i) {
    if (entries_[i].name == name) return static_cast<GatewayId>(i);
  }
  return std::nullopt;
}

// The first reason `hello` may not bind, "" when it may. Like the configuration check of one
// file (NodeMap::add_module), a refusal names both owners and the first id they share.
std::string GatewayTable::conflict(const Hello& hello) const {
  if (std::string why = module_conflict(hello); !why.empty()) return why;
  if (!hello.claims) return {};
  // Surface node ids first (what an operator maps), then the COB-IDs their profiles imply.
  if (std::string why = node_conflict(hello); !why.empty()) return why;
  return cob_conflict(hello);
}

// A module announced twice, the name held by another live process, or a module another
// connected gateway serves.
std::string GatewayTable::module_conflict(const Hello& hello) const {
  const std::string self = quoted(hello.name);
  const auto& wanted = hello.modules;
  for (auto it = wanted.begin(); it != wanted.end(); ++it) {
    if (std::find(wanted.begin(), it, *it) != it) {
      return self + " announces module " + std::to_string(*it) +
             " twice: give each module of its configuration its own id";
    }
  }
  const std::optional<GatewayId> me = find(hello.name);
  if (me && entries_[*me].connected && entries_[*me].session_id != hello.session_id) {
    return "another gateway named '" + hello.name + "' is already connected to surface '" +
           surface_name_ + "' (another process): give this gateway another name, or stop the " +
           "other process";
  }
  for (const Entry& other : entries_) {
    if (!other.connected || other.name == hello.name) continue;
    for (ModuleId m : wanted) {
      if (std::find(other.modules.begin(), other.modules.end(), m) != other.modules.end()) {
        return "module " + std::to_string(m) + " is already served by " + quoted(other.name) +
               ", connected to surface '" + surface_name_ + "'; " + self +
               " refused: give this gateway another name or module, or stop " + quoted(other.name);
      }
    }
  }
  return {};
}

// A claim held by a connected gateway other than `name` (its own, earlier session is no rival).
bool GatewayTable::held_by_other(std::int32_t owner, const std::string& name) const {
  return owner != kNobody && entries_[static_cast<std::size_t>(owner)].connected &&
         entries_[static_cast<std::size_t>(owner)].name != name;
}

// The refusal names the first shared id and counts the overlap with that same owner, so the
// operator sees the size of the clash with one gateway, not a mix of several.
std::string GatewayTable::node_conflict(const Hello& hello) const {
  const std::string self = quoted(hello.name);
  std::int32_t first_owner = kNobody;
  std::size_t overlaps = 0;
  std::string first;
  for (const ModuleClaim& m : hello.claims->modules) {
    for (NodeId node : m.surface_nodes) {
      const std::int32_t owner = node_owner_[node];
      if (!held_by_other(owner, hello.name) || (first_owner != kNobody && owner != first_owner))
        continue;
      if (overlaps++ != 0) continue;
      first_owner = owner;
      const Entry& other = entries_[static_cast<std::size_t>(owner)];
      first = "surface node id " + std::to_string(node) + " of " + self + " module " +
              std::to_string(m.id) + " is already " + quoted(other.name) + " module " +
              std::to_string(other.claims ? module_with_node(*other.claims, node) : 0) +
              "'s, connected to surface '" + surface_name_ + "'";
    }
  }
  if (overlaps == 0) return {};
  const std::string& other = entries_[static_cast<std::size_t>(first_owner)].name;
  return first + (overlaps > 1 ? " (" + std::to_string(overlaps) + " ids overlap in all)" : "") +
         "; " + self + " refused: map its nodes to surface ids " + quoted(other) + " does not use";
}

// As node_conflict, for the surface COB-IDs the claimed nodes' profiles use.
std::string GatewayTable::cob_conflict(const Hello& hello) const {
  const std::string self = quoted(hello.name);
  std::int32_t first_owner = kNobody;
  std::size_t overlaps = 0;
  std::string first;
  for (const ModuleClaim& m : hello.claims->modules) {
    for (const CobRange& r : m.cob_ranges) {
      for (std::uint32_t cob = r.first; cob <= r.last; ++cob) {
        const std::int32_t owner = cob_owner_[cob];
        if (!held_by_other(owner, hello.name) || (first_owner != kNobody && owner != first_owner))
          continue;
        if (overlaps++ != 0) continue;
        first_owner = owner;
        const Entry& other = entries_[static_cast<std::size_t>(owner)];
        first = "surface COB-ID " + hex_cob(cob) + " of " + self + " module " +
                std::to_string(m.id) + " collides with " + quoted(other.name) + " module " +
                std::to_string(other.claims ? module_with_cob(*other.claims, cob) : 0) +
                ", connected to surface '" + surface_name_ + "'";
      }
    }
  }
  if (overlaps == 0) return {};
  const std::string& other = entries_[static_cast<std::size_t>(first_owner)].name;
  return first +
         (overlaps > 1 ? " (" + std::to_string(overlaps) + " COB-IDs collide in all)" : "") + "; " +
         self + " refused: give its nodes surface ids whose COB-IDs " + quoted(other) +
         " does not use";
}

GatewayTable::Admission GatewayTable::admit(const Hello& hello) {
  std::string why = conflict(hello);
  if (!why.empty()) {
    std::string& last = last_refusal_[hello.name];
    const bool repeated = last == why;
    last = why;
    return {std::nullopt, std::move(why), repeated};
  }
  last_refusal_.erase(hello.name);
  std::optional<GatewayId> id = find(hello.name);
  if (!id) {
    id = static_cast<GatewayId>(entries_.size());
    entries_.push_back({hello.name, 0, {}, std::nullopt, false});
  }
  Entry& e = entries_[*id];
  e.session_id = hello.session_id;
  e.modules = hello.modules;
  e.claims = hello.claims;
  take_claims(*id);
  return {id, {}, false};
}

void GatewayTable::take_claims(GatewayId gateway) {
  const auto me = static_cast<std::int32_t>(gateway);
  std::replace(node_owner_.begin(), node_owner_.end(), me, kNobody);
  std::replace(cob_owner_.begin(), cob_owner_.end(), me, kNobody);
  const Entry& e = entries_[gateway];
  if (!e.claims) return;
  // Ids held by a disconnected gateway pass to this one: conflict() let it through.
  for (const ModuleClaim& m : e.claims->modules) {
    for (NodeId node : m.surface_nodes) node_owner_[node] = me;
    for (const CobRange& r : m.cob_ranges) {
      std::fill(cob_owner_.begin() + r.first, cob_owner_.begin() + r.last + 1, me);
    }
  }
}

std::string GatewayTable::update_claims(GatewayId gateway, GatewayClaims claims) {
  if (gateway >= entries_.size()) return "no such gateway";
  Entry& e = entries_[gateway];
  std::string why = conflict({e.name, e.session_id, e.modules, claims});
  if (!why.empty()) return why;
  e.claims = std::move(claims);
  take_claims(gateway);
  return {};
}

void GatewayTable::set_connected(GatewayId gateway, bool connected) {
  if (gateway < entries_.size()) entries_[gateway].connected = connected;
}

std::optional<GatewayTable::GatewayId> GatewayTable::owner_of_node(NodeId surface_node) const {
  if (surface_node == 0 || surface_node > canopen::kMaxNodeId) return std::nullopt;
  const std::int32_t owner = node_owner_[surface_node];
  if (owner == kNobody) return std::nullopt;
  return static_cast<GatewayId>(owner);
}

std::optional<GatewayTable::GatewayId> GatewayTable::owner_of_cob(std::uint32_t surface_cob) const {
  if (surface_cob >= kStandardCobIds) return std::nullopt;
  const std::int32_t owner = cob_owner_[surface_cob];
  if (owner == kNobody) return std::nullopt;
  return static_cast<GatewayId>(owner);
}

GatewayTable::Route GatewayTable::route(const can::Frame& frame) const {
  if (frame.is_extended()) return {};
  if (frame.id == canopen::cob::nmt) {
    if (frame.len < 2 || frame.is_remote() || frame.data[1] == 0) return {};  // all
    if (auto owner = owner_of_node(frame.data[1])) return {Route::one, *owner};
    return {Route::unclaimed, 0, Unrouted::unclaimed_node};
  }
  if (frame.id == canopen::cob::sync || frame.id == canopen::cob::time) return {};
  if (auto owner = owner_of_cob(frame.id)) return {Route::one, *owner};
  if (canopen::split_predefined(frame.id)) return {Route::unclaimed, 0, Unrouted::unclaimed_node};
  return {};
}

}  // namespace canbridge::bridge
