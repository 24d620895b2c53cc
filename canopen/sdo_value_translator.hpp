// Rewrites the values of objects that hold COB-IDs or node ids (SDO and PDO communication
// parameters, EMCY COB-ID, heartbeat consumer entries) inside expedited SDO transfers, so that a
// master on the surface reads and writes surface ids while the node keeps its module-bus ids.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>

#include "can/frame.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::canopen::sdo {

// What an object's 32-bit (or 8-bit) value holds.
enum class ValueKind {
  none,           // an ordinary value: never rewritten
  cob_id,         // COB-ID entry: bits 0-10 (or 0-28 with bit 29) the id, bits 29-31 flags
  node_in_16_23,  // heartbeat consumer entry (1016h): producer node id in bits 16-23
  node_id,        // UNSIGNED8 node id (SDO parameters 1200h-12FFh sub-index 3)
};

// The objects of CiA 301 whose values name COB-IDs or nodes, in the node's own id space:
// SDO server parameters 1200h-127Fh sub 1-2 (COB-IDs) and sub 3 (client node id), SDO client
// parameters 1280h-12FFh sub 1-2 (COB-IDs) and sub 3 (server node id), RPDO 1400h-15FFh and
// TPDO 1800h-19FFh sub 1, EMCY 1014h, heartbeat consumer 1016h sub 1-127, emergency consumer
// 1028h sub 1-127 (EMCY COB-IDs). SYNC (1005h) and TIME (1012h) COB-IDs are network-wide, the
// same on every bus, and are not listed.
ValueKind value_kind(Multiplexer mux);

// One direction of the id mapping (module bus -> surface, or back), from the bridge's id profile.
// Either function returns nullopt for an id that has no counterpart.
struct IdMapping {
  std::function<std::optional<std::uint32_t>(std::uint32_t cob_id)> cob_id;
  std::function<std::optional<NodeId>(NodeId node)> node_id;
};

// `value` of `kind` seen through `map`: flag bits kept, the id (or node id) replaced. A 29-bit
// COB-ID (bit 29), node id 0 (an unused consumer entry) and ids the map does not know are
// returned unchanged, with `mapped` false for the last case.
struct TranslatedValue {
  std::uint32_t value;
  bool mapped;
};
TranslatedValue translate_value(ValueKind kind, std::uint32_t value, const IdMapping& map);

// What happened to one SDO frame.
enum class ValueRewrite {
  unchanged,       // not an expedited transfer of a listed object
  rewritten,       // its value now speaks the other side's ids
  no_counterpart,  // a listed object whose id maps nowhere: forwarded unchanged (counted)
};

// Frame-level rewriting, stateless: an expedited initiate-download request and an expedited
// initiate-upload response both carry their object's multiplexer, and every listed object fits
// in 4 bytes, so each frame says by itself which object its value belongs to.
// `request`: client -> server (surface master -> node), rewritten with `to_local`.
ValueRewrite rewrite_request(can::Frame& request, const IdMapping& to_local);
// `response`: server -> client (node -> surface master), rewritten with `to_surface`.
ValueRewrite rewrite_response(can::Frame& response, const IdMapping& to_surface);

}  // namespace canbridge::canopen::sdo
