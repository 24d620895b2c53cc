#include "bridge/gateway_table.hpp"

#include <algorithm>
#include <cstdio>
#include <map>
#include <stdexcept>

#include "canopen/cob_id.hpp"
#include "routing/id_profile.hpp"

namespace canbridge::bridge {

namespace {

// A peer-chosen name, safe for a log line: at most 64 characters, printable ASCII only.
std::string printable(std::string_view text) {
  std::string out(text.substr(0, 64));
  for (char& c : out) {
    if (c < 0x20 || c > 0x7E) c = '?';
  }
  if (text.size() > out.size()) out += "...";
  return out;
}

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

const char* to_string(NotItsOwn reason) {
  switch (reason) {
    case NotItsOwn::master_only:
      return "master-only";
    case NotItsOwn::outside_claims:
      return "outside-claims";
    case NotItsOwn::extended:
      return "extended";
    case NotItsOwn::count_:
      break;
  }
  return "unknown";
}

std::bitset<kStandardCobIds> cob_image_of(const std::bitset<128>& surface_nodes) {
  std::bitset<kStandardCobIds> image;
  for (IdProfile profile : {IdProfile::cia301, IdProfile::pdop, IdProfile::qd}) {
    for (NodeId node = 1; node <= max_node_id(profile); ++node) {
      if (!surface_nodes.test(node)) continue;
      for (const ProfileCobId& id : profile_cob_ids(profile)) image.set(id.base + node);
    }
  }
  return image;
}

GatewayTable::GatewayTable(std::string surface_name, const std::vector<AcceptedGateway>& accepted,
                           bool require_authenticated_peers)
    : surface_name_(std::move(surface_name)),
      require_authenticated_peers_(require_authenticated_peers) {
  node_owner_.fill(kNobody);
  cob_owner_.fill(kNobody);
  std::map<ModuleId, std::string> module_of;
  std::array<const std::string*, 128> node_of{};
  for (const AcceptedGateway& g : accepted) {
    if (g.name.empty() || find(g.name)) {
      throw std::invalid_argument("accepted gateways: the name '" + g.name +
                                  "' is empty or given twice");
    }
    Allowance allowance;
    allowance.modules = g.modules;
    for (ModuleId m : g.modules) {
      if (auto [it, fresh] = module_of.emplace(m, g.name); !fresh) {
        throw std::invalid_argument("accepted gateways: module " + std::to_string(m) +
                                    " is given to both gateway '" + it->second + "' and '" +
                                    g.name + "'");
      }
      if (!g.surface_nodes.empty()) continue;
      for (auto [local, surface] : NodeMap::default_pairs(m)) allowance.nodes.set(surface);
    }
    for (NodeId node : g.surface_nodes) {
      if (node == 0 || node > canopen::kMaxNodeId) {
        throw std::invalid_argument("accepted gateways: gateway '" + g.name + "' surface node " +
                                    std::to_string(node) + " is outside 1..127");
      }
      allowance.nodes.set(node);
    }
    for (NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
      if (!allowance.nodes.test(node)) continue;
      if (node_of[node] && *node_of[node] != g.name) {
        throw std::invalid_argument("accepted gateways: surface node " + std::to_string(node) +
                                    " is given to both gateway '" + *node_of[node] + "' and '" +
                                    g.name + "'");
      }
    }
    allowance.cobs = cob_image_of(allowance.nodes);
    entries_.push_back({g.name, 0, {}, std::nullopt, false, false});
    for (NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
      if (allowance.nodes.test(node)) node_of[node] = &entries_.back().name;
    }
    allowed_.push_back(std::move(allowance));
  }
  accepted_.resize(entries_.size());
  last_refusal_.resize(entries_.size());
}

std::optional<GatewayTable::GatewayId> GatewayTable::find(std::string_view name) const {
  for (std::size_t i = 0; i < entries_.size(); ++i) {
    if (entries_[i].name == name) return static_cast<GatewayId>(i);
  }
  return std::nullopt;
}

// Who the peer is: a configured name, the one its link proved, and proven when that is required.
std::string GatewayTable::identity_problem(const Hello& hello) const {
  const std::string self = quoted(printable(hello.name));
  if (!find(hello.name)) {
    return self + " is not configured on surface '" + surface_name_ +
           "': add it to the surface's `gateways:` (name, modules) if it belongs";
  }
  if (!hello.authenticated_peer.empty() && hello.authenticated_peer != hello.name) {
    return "the link proved identity '" + printable(hello.authenticated_peer) +
           "' but its hello names " + self +
           ": give the gateway the name of its key or certificate";
  }
  if (hello.authenticated_peer.empty() && require_authenticated_peers_) {
    return self + " proved no identity, and surface '" + surface_name_ +
           "' accepts authenticated gateways only: give both the same auth mode and key";
  }
  return {};
}

// Modules and claims within what the configuration gives this gateway.
std::string GatewayTable::allowance_problem(GatewayId gateway, const std::vector<ModuleId>& modules,
                                            const std::optional<GatewayClaims>& claims) const {
  const Allowance& allowed = allowed_[gateway];
  const std::string self = quoted(entries_[gateway].name);
  const std::string fix = ": configured on surface '" + surface_name_ +
                          "' for other ones; change its `gateways:` entry or the gateway's file";
  auto allowed_module = [&](ModuleId m) {
    return std::find(allowed.modules.begin(), allowed.modules.end(), m) != allowed.modules.end();
  };
  for (ModuleId m : modules) {
    if (!allowed_module(m)) return self + " announces module " + std::to_string(m) + fix;
  }
  if (!claims) return {};
  for (const ModuleClaim& claim : claims->modules) {
    if (std::find(modules.begin(), modules.end(), claim.id) == modules.end()) {
      return self + " claims ids for module " + std::to_string(claim.id) +
             ", which it does not announce";
    }
    for (NodeId node : claim.surface_nodes) {
      if (!allowed.nodes.test(node)) {
        return self + " module " + std::to_string(claim.id) + " claims surface node id " +
               std::to_string(node) + fix;
      }
    }
    for (const CobRange& r : claim.cob_ranges) {
      for (std::uint32_t cob = r.first; cob <= r.last; ++cob) {
        if (!allowed.cobs.test(cob)) {
          return self + " module " + std::to_string(claim.id) + " claims surface COB-ID " +
                 hex_cob(cob) + ", which none of its configured surface node ids uses" + fix;
        }
      }
    }
  }
  return {};
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

// A module announced twice, or the name held by another live process.
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
  // Another gateway's modules are outside this one's configuration: allowance_problem().
  return {};
}

// A claim another gateway holds, up or down: a gateway away keeps its ids (its own earlier
// session is no rival).
bool GatewayTable::held_by_other(std::int32_t owner, const std::string& name) const {
  return owner != kNobody && entries_[static_cast<std::size_t>(owner)].name != name;
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
              "'s on surface '" + surface_name_ + "'";
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
                ", on surface '" + surface_name_ + "'";
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

GatewayTable::Admission GatewayTable::refuse(const Hello& hello, std::optional<GatewayId> gateway,
                                             std::string why) {
  // Strangers share one slot: their names leave nothing behind.
  std::string& last = gateway ? last_refusal_[*gateway] : last_stranger_refusal_;
  const bool repeated = last == why;
  last = why;
  std::string to_peer = hello.authenticated_peer.empty() ? std::string("refused") : why;
  return {std::nullopt, std::move(why), std::move(to_peer), repeated, !gateway.has_value()};
}

GatewayTable::Admission GatewayTable::admit(const Hello& hello) {
  if (std::string why = identity_problem(hello); !why.empty()) {
    // A configured name that proved nothing (or another identity) is no proof of being it.
    return refuse(hello, std::nullopt, std::move(why));
  }
  const GatewayId id = *find(hello.name);
  std::string why = allowance_problem(id, hello.modules, hello.claims);
  if (why.empty()) why = conflict(hello);
  if (!why.empty()) return refuse(hello, id, std::move(why));
  last_refusal_[id].clear();
  Entry& e = entries_[id];
  e.session_id = hello.session_id;
  e.modules = hello.modules;
  e.claims = hello.claims;
  e.bound_once = true;
  take_claims(id);
  return {id, {}, {}, false, false};
}

void GatewayTable::take_claims(GatewayId gateway) {
  const auto me = static_cast<std::int32_t>(gateway);
  std::replace(node_owner_.begin(), node_owner_.end(), me, kNobody);
  std::replace(cob_owner_.begin(), cob_owner_.end(), me, kNobody);
  const Entry& e = entries_[gateway];
  Accepted& accepted = accepted_[gateway];
  if (!e.claims) {
    // A gateway without claims (protocol minor < 3): what its configuration allows.
    accepted.nodes = allowed_[gateway].nodes;
    accepted.cobs = allowed_[gateway].cobs;
    return;
  }
  accepted = {};
  for (const ModuleClaim& m : e.claims->modules) {
    for (NodeId node : m.surface_nodes) {
      node_owner_[node] = me;
      accepted.nodes.set(node);
    }
    for (const CobRange& r : m.cob_ranges) {
      std::fill(cob_owner_.begin() + r.first, cob_owner_.begin() + r.last + 1, me);
      for (std::uint32_t cob = r.first; cob <= r.last; ++cob) accepted.cobs.set(cob);
    }
  }
}

std::string GatewayTable::update_claims(GatewayId gateway, GatewayClaims claims) {
  if (gateway >= entries_.size()) return "no such gateway";
  Entry& e = entries_[gateway];
  std::string why = allowance_problem(gateway, e.modules, claims);
  if (why.empty()) why = conflict({e.name, e.session_id, e.modules, claims, {}});
  if (!why.empty()) return why;
  e.claims = std::move(claims);
  take_claims(gateway);
  return {};
}

void GatewayTable::set_connected(GatewayId gateway, bool connected) {
  if (gateway < entries_.size()) entries_[gateway].connected = connected;
}

std::optional<NotItsOwn> GatewayTable::refuses(GatewayId gateway, const can::Frame& frame) const {
  if (frame.is_extended()) return NotItsOwn::extended;
  if (frame.id == canopen::cob::lss_slave) return std::nullopt;
  if (frame.id == canopen::cob::nmt || frame.id == canopen::cob::sync ||
      frame.id == canopen::cob::time || frame.id == canopen::cob::lss_master) {
    return NotItsOwn::master_only;
  }
  if (gateway >= accepted_.size() || !accepted_[gateway].cobs.test(frame.id)) {
    return NotItsOwn::outside_claims;
  }
  return std::nullopt;
}

bool GatewayTable::speaks_for(GatewayId gateway, NodeId node) const {
  return gateway < accepted_.size() && node <= canopen::kMaxNodeId &&
         accepted_[gateway].nodes.test(node);
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
