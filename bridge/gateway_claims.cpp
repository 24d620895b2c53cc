#include "bridge/gateway_claims.hpp"

#include <algorithm>

#include "canbridge.pb.h"

namespace canbridge::bridge {

GatewayClaims claims_of(const NodeMap& map) {
  GatewayClaims claims;
  for (const ModuleNodes& m : map.modules()) {
    ModuleClaim& claim = claims.modules.emplace_back();
    claim.id = m.id;
    for (NodeId surface : m.local_to_surface) {
      if (surface != 0) claim.surface_nodes.push_back(surface);
    }
    std::sort(claim.surface_nodes.begin(), claim.surface_nodes.end());
    std::vector<std::uint16_t> cobs;
    for (std::uint16_t surface_cob : m.local_to_surface_cob) {
      if (surface_cob != 0) cobs.push_back(surface_cob);
    }
    std::sort(cobs.begin(), cobs.end());
    // Runs of consecutive COB-IDs (a function code's block of nodes) become one range each.
    for (std::uint16_t cob : cobs) {
      if (!claim.cob_ranges.empty() && claim.cob_ranges.back().last + 1 == cob) {
        claim.cob_ranges.back().last = cob;
      } else {
        claim.cob_ranges.push_back({cob, cob});
      }
    }
  }
  return claims;
}

std::string encode_claims(const GatewayClaims& claims) {
  v1::GatewayClaims out;
  for (const ModuleClaim& m : claims.modules) {
    v1::GatewayClaims::Module& module = *out.add_modules();
    module.set_module_id(m.id);
    for (NodeId node : m.surface_nodes) module.add_surface_nodes(node);
    for (const CobRange& r : m.cob_ranges) {
      v1::GatewayClaims::CobRange& range = *module.add_cob_ranges();
      range.set_first(r.first);
      range.set_last(r.last);
    }
  }
  return out.SerializeAsString();
}

std::optional<GatewayClaims> decode_claims(std::string_view bytes) {
  v1::GatewayClaims in;
  if (!in.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) return std::nullopt;
  GatewayClaims claims;
  for (const v1::GatewayClaims::Module& module : in.modules()) {
    ModuleClaim& m = claims.modules.emplace_back();
    m.id = module.module_id();
    for (std::uint32_t node : module.surface_nodes()) {
      if (node == 0 || node > canopen::kMaxNodeId) return std::nullopt;
      m.surface_nodes.push_back(static_cast<NodeId>(node));
    }
    for (const v1::GatewayClaims::CobRange& range : module.cob_ranges()) {
      if (range.first() > range.last() || range.last() >= kStandardCobIds) return std::nullopt;
      m.cob_ranges.push_back(
          {static_cast<std::uint16_t>(range.first()), static_cast<std::uint16_t>(range.last())});
    }
  }
  return claims;
}

}  // namespace canbridge::bridge
