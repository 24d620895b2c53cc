// Rewrites COB-IDs and NMT node ids between each module bus and the one surface network.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "can/frame.hpp"
#include "canopen/nmt_node_id.hpp"
#include "routing/node_map.hpp"

namespace canbridge::bridge {

// Why a frame was not forwarded. Every frame the translator refuses is counted under one.
enum class DropReason : std::uint8_t {
  extended_id,     // 29-bit frames are not part of the predefined connection set
  unknown_node,    // node-addressed COB-ID of a node id nobody maps
  not_routable,    // COB-ID with no owner in that direction (e.g. SYNC/TIME/NMT from a module)
  malformed_nmt,   // NMT frame shorter than 2 bytes
  rename_refused,  // set-node-id command to a surface id the node cannot take (rename_refusal)
  lss_unrouted,    // LSS frame while no module is selected for LSS, or from another module
  count_
};
inline constexpr std::size_t kDropReasonCount = static_cast<std::size_t>(DropReason::count_);
const char* to_string(DropReason reason);

using DropCounters = std::array<std::uint64_t, kDropReasonCount>;

// The last set-node-id command the translator refused, for the gateway's log and the surface.
struct RenameRefusal {
  std::optional<NodeOwner> node;  // the commanded node, when the map has it
  NodeId surface = 0;             // the command's current surface id (0: by serial)
  NodeId next_surface = 0;        // the surface id it asked for
  std::string reason;
};

// Pure translation: no I/O, no clock. One instance per gateway, shared by all its modules. The
// map is live: a set-node-id command to a free surface id plans the node's move in it
// (NodeMap::plan_move), which the gateway applies when the node's boot-up confirms it.
class CobIdTranslator {
 public:
  explicit CobIdTranslator(NodeMap& map) : map_(map) {}

  // The one module LSS (CiA 305, 0x7E5/0x7E4) reaches: LSS addresses "every unconfigured node
  // on the bus", so letting it reach several buses at once would make their nodes answer and
  // switch together. nullopt (the default) routes no LSS at all.
  void route_lss_to(std::optional<std::size_t> module_index) { lss_module_ = module_index; }
  std::optional<std::size_t> lss_module() const { return lss_module_; }

  // A frame read on module `module_index`'s bus, as the surface must see it; nullopt if it maps
  // nowhere (counted).
  std::optional<can::Frame> to_surface(std::size_t module_index, const can::Frame& frame);

  // A frame from the surface network: calls emit(module_index, frame) once for every module
  // that must receive it (translated for that module). Returns false if no module gets it.
  template <typename Emit>
  bool to_modules(const can::Frame& frame, Emit&& emit);

  const DropCounters& drops() const { return drops_; }
  std::uint64_t dropped(DropReason reason) const {
    return drops_[static_cast<std::size_t>(reason)];
  }
  // Why the last counted rename_refused was refused.
  const RenameRefusal& rename_refusal() const { return refusal_; }

 private:
  void count(DropReason r) { ++drops_[static_cast<std::size_t>(r)]; }
  bool refuse_rename(std::optional<NodeOwner> node, NodeId surface, NodeId next_surface,
                     std::string reason);
  // `E0 cc nn` (surface ids) for `owner`, the node of cc: fills in local's byte 2, or refuses.
  bool translate_change(const can::Frame& frame, const NodeOwner& owner, can::Frame& local);

  // LSS configure node-id (cs 11h) carries the new node id in byte 1: a surface id on the
  // surface, the local id on the module bus; FFh ("unconfigured") passes unchanged.
  static constexpr std::uint8_t kLssConfigureNodeId = 0x11;
  static constexpr std::uint8_t kLssInquireNodeId = 0x5E;  // the response carries it in byte 1
  static constexpr std::uint8_t kLssUnconfigured = 0xFF;

  NodeMap& map_;
  DropCounters drops_{};
  RenameRefusal refusal_;
  std::optional<std::size_t> lss_module_;
};

template <typename Emit>
bool CobIdTranslator::to_modules(const can::Frame& frame, Emit&& emit) {
  if (frame.is_extended()) {
    count(DropReason::extended_id);
    return false;
  }
  const std::size_t module_count = map_.modules().size();
  if (frame.id == canopen::cob::nmt) {
    if (frame.len < 2 || frame.is_remote()) {
      count(DropReason::malformed_nmt);
      return false;
    }
    // Node-specific NMT addresses surface node ids, i.e. slot 0 of a pdop/qd node. The fpga
    // kind's set-node-id commands (docs/nmt-node-id.md) also name the target in byte 1.
    const NodeId target = frame.data[1];
    if (target == 0) {  // broadcast: every module, unchanged
      for (std::size_t m = 0; m < module_count; ++m) emit(m, frame);
      return module_count != 0;
    }
    auto owner = map_.owner_of_surface(target);
    if (!owner) {
      if (frame.len == 6 && frame.data[0] == canopen::nmt_node_id::kBySerial) {
        return refuse_rename(std::nullopt, 0, target,
                             "set-node-id by serial to surface id " + std::to_string(target) +
                                 ", which no module maps: a serial does not say which bus the "
                                 "node is on; rename it by its id (E0) instead");
      }
      count(DropReason::unknown_node);
      return false;
    }
    can::Frame local = frame;
    local.data[1] = owner->local;
    // (Surface ids may exceed the 5-bit range the node accepts: only the layout is checked here.)
    if (frame.len == 3 && frame.data[0] == canopen::nmt_node_id::kChange && frame.data[2] != 0 &&
        !translate_change(frame, *owner, local)) {
      return false;
    }
    emit(owner->module_index, local);
    return true;
  }
  if (frame.id == canopen::cob::lss_master) {
    if (!lss_module_) {
      count(DropReason::lss_unrouted);
      return false;
    }
    can::Frame local = frame;
    if (frame.len >= 2 && frame.data[0] == kLssConfigureNodeId &&
        frame.data[1] != kLssUnconfigured) {
      auto owner = map_.owner_of_surface(frame.data[1]);
      if (!owner || owner->module_index != *lss_module_) {
        count(DropReason::unknown_node);
        return false;
      }
      local.data[1] = owner->local;
    }
    emit(*lss_module_, local);
    return true;
  }
  if (frame.id == canopen::cob::sync || frame.id == canopen::cob::time) {
    for (std::size_t m = 0; m < module_count; ++m) emit(m, frame);
    return module_count != 0;
  }
  // Every module's image is in one table, whatever its profile: the owner and its local COB-ID.
  auto owner = map_.owner_of_surface_cob(frame.id);
  if (!owner) {
    // A CiA 301 node-addressed COB-ID nobody owns is an unknown node; the rest is never routed.
    count(canopen::split_predefined(frame.id) ? DropReason::unknown_node
                                              : DropReason::not_routable);
    return false;
  }
  can::Frame local = frame;
  local.id = owner->local_cob;
  emit(owner->module_index, local);
  return true;
}

}  // namespace canbridge::bridge
