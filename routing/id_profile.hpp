// Per-module CANopen identifier profiles: which COB-IDs each node of a module bus owns.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "canopen/cob_id.hpp"

namespace canbridge::bridge {

// How a module bus lays out node-addressed COB-IDs (docs/id-profiles.md). The surface network
// is always CiA 301.
enum class IdProfile : std::uint8_t {
  cia301,  // node id 1..127 in bits 6-0 (predefined connection set)
  pdop,    // PDO Packets (seed 000): bits 6-5 are toggle/continued on PDOs, node id 1..31
  qd,      // extended connection set (seed 003): node 1..31 also owns slots 1..3 (bits 6-5)
};

const char* to_string(IdProfile profile);
std::optional<IdProfile> parse_id_profile(std::string_view text);

// Largest node id of the profile: with bits 6-5 taken, pdop and qd buses address 1..31 only.
constexpr canopen::NodeId max_node_id(IdProfile profile) {
  return profile == IdProfile::cia301 ? canopen::kMaxNodeId : canopen::NodeId{31};
}

// One COB-ID every node of a profile owns: base + node id, the same on both sides of the
// bridge, so translating is replacing the node id (slot bits 6-5 travel within `base`).
struct ProfileCobId {
  std::uint16_t base;
  std::string name;  // e.g. "TPDO2", "SDO tx", "TPDO1 t=1 c=0": for problem messages
};

// All COB-IDs one node owns under `profile`, in a fixed order.
const std::vector<ProfileCobId>& profile_cob_ids(IdProfile profile);

// True when `cob_id` is node-addressed under `profile` for some node 1..max_node_id (an owner
// may still be missing): tells an unknown node from a COB-ID that is never routed.
bool is_node_addressed(IdProfile profile, std::uint32_t cob_id);

}  // namespace canbridge::bridge
