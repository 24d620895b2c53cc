// Default PDO COB-IDs of each simulated node kind: the CiA 301 predefined connection set, and the
// QD-CANopen set of 34 TPDOs per node (seeds/003 figure 4, seeds/001).
#pragma once

#include <cstdint>
#include <optional>

#include "canopen/cob_id.hpp"
#include "sim/node_spec.hpp"

namespace canbridge::sim {

// How many TPDOs / RPDOs a node of the kind has by default (qd: 34 TPDOs, others 4; all 4 RPDOs).
unsigned max_tpdos(NodeKind kind);
unsigned max_rpdos(NodeKind kind);

// Default COB-ID (without bit 31) of TPDO/RPDO `number` (1-based) of node `node` for the kind;
// nullopt when the number is out of range or the node id is outside the kind's range (qd: 1..31,
// because its extra TPDOs borrow the ids of nodes N+32, N+64 and N+96; others: 1..127).
std::optional<std::uint32_t> default_tpdo_cob_id(NodeKind kind, canopen::NodeId node,
                                                 unsigned number);
std::optional<std::uint32_t> default_rpdo_cob_id(NodeKind kind, canopen::NodeId node,
                                                 unsigned number);

}  // namespace canbridge::sim
