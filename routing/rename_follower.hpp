// Moves nodes in a gateway's live NodeMap as its node table confirms renames by the fpga node-id
// command (docs/nmt-node-id.md), so that the surface view follows a node to its new id.
#pragma once

#include <string>

#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

// What following one node event did to the map.
struct RenameFollowed {
  enum class Change : std::uint8_t {
    none,     // the event moves nothing
    moved,    // the node's pair moved: its frames now translate to its new surface id
    refused,  // the node could not take the surface id (reason): the map is unchanged
  };
  Change change = Change::none;
  std::string reason;  // refused only
};

// Applies `event` to `map`, before the frames that follow it are translated (the boot-up that
// confirms a rename must already cross under the new id):
// - booted of a node whose move was planned (a surface master's `E0 cc nn` to a free surface id,
//   sent as `E0 cc cc`): the node takes the planned surface id, its old one is freed, and the
//   event becomes `renamed` (previous_local = local, previous_surface = the old surface id);
// - renamed from F to a local id L the module does not map (a master on the module bus, or a
//   by-serial command): the pair of F moves to L with its surface id, so the node stays where
//   the surface sees it; F unmapped: refused (the node has no surface id to keep);
// - rename_unconfirmed of a planned command (local == previous_local): the plan is dropped.
// A renamed event names its previous surface id in `previous_surface` (0: the map had none).
RenameFollowed follow_rename(NodeMap& map, NodeEvent& event);

}  // namespace canbridge::bridge
