// What a gateway serves on the surface (its modules, their surface node ids and COB-IDs), as
// the gateway announces it in its hello and the surface's gateway table checks and routes by.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "routing/node_map.hpp"

namespace canbridge::bridge {

// Surface COB-IDs first..last, inclusive.
struct CobRange {
  std::uint16_t first = 0;
  std::uint16_t last = 0;
  friend bool operator==(const CobRange&, const CobRange&) = default;
};

struct ModuleClaim {
  ModuleId id = 0;
  std::vector<NodeId> surface_nodes;  // ascending
  std::vector<CobRange> cob_ranges;   // ascending, disjoint, not adjacent
  friend bool operator==(const ModuleClaim&, const ModuleClaim&) = default;
};

struct GatewayClaims {
  std::vector<ModuleClaim> modules;
  friend bool operator==(const GatewayClaims&, const GatewayClaims&) = default;
};

// The claims of every module of `map`: its mapped surface node ids and its surface COB-ID image.
GatewayClaims claims_of(const NodeMap& map);

// Hello.application bytes (a canbridge.v1.GatewayClaims) and back. decode_claims refuses bytes
// that are not a GatewayClaims or name a node outside 1..127 or a COB-ID outside 0..0x7FF.
std::string encode_claims(const GatewayClaims& claims);
std::optional<GatewayClaims> decode_claims(std::string_view bytes);

}  // namespace canbridge::bridge
