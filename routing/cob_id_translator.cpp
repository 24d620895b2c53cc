#include "routing/cob_id_translator.hpp"

#include <utility>

namespace canbridge::bridge {

const char* to_string(DropReason reason) {
  switch (reason) {
    case DropReason::extended_id:
      return "extended-id";
    case DropReason::unknown_node:
      return "unknown-node";
    case DropReason::not_routable:
      return "not-routable";
    case DropReason::malformed_nmt:
      return "malformed-nmt";
    case DropReason::rename_refused:
      return "rename-refused";
    case DropReason::lss_unrouted:
      return "lss-unrouted";
    case DropReason::count_:
      break;
  }
  return "unknown";
}

bool CobIdTranslator::refuse_rename(std::optional<NodeOwner> node, NodeId surface,
                                    NodeId next_surface, std::string reason) {
  count(DropReason::rename_refused);
  refusal_ = RenameRefusal{node, surface, next_surface, std::move(reason)};
  return false;
}

bool CobIdTranslator::translate_change(const can::Frame& frame, const NodeOwner& owner,
                                       can::Frame& local) {
  const NodeId surface = frame.data[1];
  const NodeId next_surface = frame.data[2];
  const auto next = map_.owner_of_surface(next_surface);
  if (next && next->module_index == owner.module_index) {
    local.data[2] = next->local;  // a node of the same bus: it takes that local id
    return true;
  }
  const std::string what = "set-node-id of surface node " + std::to_string(surface) + " to " +
                           std::to_string(next_surface) + ": ";
  if (next) {
    // A node cannot move to another bus.
    return refuse_rename(owner, surface, next_surface,
                         what + "that id belongs to module " +
                             std::to_string(map_.modules()[next->module_index].id) + " node " +
                             std::to_string(next->local) + ", on another bus");
  }
  // A free surface id: the node keeps its local id (`E0 cc cc`, a reset communication the node
  // confirms with its boot-up, docs/nmt-node-id.md) and its pair moves to the new surface id
  // when that boot-up comes. Its bus needs no free id, and no other node there is disturbed.
  if (!canopen::nmt_node_id::valid_node_id(owner.local)) {
    return refuse_rename(owner, surface, next_surface,
                         what + "the node's local id " + std::to_string(owner.local) +
                             " is outside the command's 1.." +
                             std::to_string(canopen::nmt_node_id::kMaxNodeId));
  }
  if (const auto problem =
          map_.move_problem(owner.module_index, owner.local, owner.local, next_surface)) {
    return refuse_rename(owner, surface, next_surface, what + *problem);
  }
  local.data[2] = owner.local;
  map_.plan_move(owner.module_index, owner.local, next_surface);
  return true;
}

std::optional<can::Frame> CobIdTranslator::to_surface(std::size_t module_index,
                                                      const can::Frame& frame) {
  if (frame.is_extended()) {
    count(DropReason::extended_id);
    return std::nullopt;
  }
  if (frame.id == canopen::cob::lss_slave) {
    if (module_index != lss_module_) {
      count(DropReason::lss_unrouted);
      return std::nullopt;
    }
    can::Frame out = frame;
    // The inquired node id, as the master must address the node: its surface id. An id the
    // module does not map goes as it is (the master cannot reach that node anyway).
    if (frame.len >= 2 && frame.data[0] == kLssInquireNodeId) {
      if (const NodeId surface = map_.surface_of(module_index, frame.data[1])) {
        out.data[1] = surface;
      }
    }
    return out;
  }
  const std::uint16_t surface = map_.surface_cob_of(module_index, frame.id);
  if (surface == 0) {
    // NMT, SYNC and TIME belong to the surface master; a module's own would collide. A
    // node-addressed COB-ID (under the module's profile) of an unmapped node is counted apart.
    const IdProfile profile = map_.modules()[module_index].profile;
    count(is_node_addressed(profile, frame.id) ? DropReason::unknown_node
                                               : DropReason::not_routable);
    return std::nullopt;
  }
  can::Frame out = frame;
  out.id = surface;
  return out;
}

}  // namespace canbridge::bridge
