#include "bridge/surface_node_states.hpp"

#include <cstdint>

#include "canopen/cob_id.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

namespace {
bool valid_local(std::uint32_t local) {
  return local >= 1 && local <= canopen::kMaxNodeId;
}
}  // namespace

bool SurfaceNodeStates::apply(GatewayId gateway, const v1::NodeEvent& event) {
  if (!valid_local(event.local_node())) return false;
  const Key key{gateway, event.module_id(), event.local_node()};
  switch (event.kind()) {
    case v1::NodeEvent::BOOTED:
    case v1::NodeEvent::STATE_CHANGED:
    case v1::NodeEvent::RECOVERED:
    case v1::NodeEvent::DISCOVERED:
      // Heard now, in the state it reports. An event for a node the surface has no record of
      // (one whose first event it missed: a surface restarted after it) adds it.
      nodes_[key] = {event.nmt_state(), false, event.in_loader(), event.surface_node(),
                     event.boot_count()};
      return true;
    case v1::NodeEvent::LOADER_BOOTED:
      nodes_[key] = {event.nmt_state(), false, true, event.surface_node(), event.boot_count()};
      return true;
    case v1::NodeEvent::LOST: {
      // The last state stays, as in the gateway's table: the node is counted lost until heard.
      Node& node = nodes_[key];
      node.lost = true;
      node.surface_node = event.surface_node();
      return true;
    }
    case v1::NodeEvent::RENAMED: {
      // Moved, not lost: the previous id's record goes without a trace (0: the gateway did not
      // know the id the node had; that record, if any, is reported lost when it stays silent).
      const std::uint32_t from = event.previous_local_node();
      if (valid_local(from) && from != event.local_node()) {
        nodes_.erase(Key{gateway, event.module_id(), from});
      }
      nodes_[key] = {event.nmt_state(), false, event.in_loader(), event.surface_node(),
                     event.boot_count()};
      return true;
    }
    case v1::NodeEvent::RENAME_UNCONFIRMED:  // no boot-up on the new id: nothing moved
    default:                                 // a kind a newer gateway sends
      return false;
  }
}

void SurfaceNodeStates::forget(GatewayId gateway) {
  nodes_.erase(nodes_.lower_bound(Key{gateway, 0, 0}),
               nodes_.upper_bound(Key{gateway, UINT32_MAX, UINT32_MAX}));
}

void SurfaceNodeStates::for_each_node(
    GatewayId gateway,
    const std::function<void(std::uint32_t, std::uint32_t, const Node&)>& f) const {
  for (auto it = nodes_.lower_bound(Key{gateway, 0, 0});
       it != nodes_.end() && std::get<0>(it->first) == gateway; ++it) {
    f(std::get<1>(it->first), std::get<2>(it->first), it->second);
  }
}

NodeSummary SurfaceNodeStates::summary(const LinkUp& link_up) const {
  NodeCounts c;
  // One link_up call per gateway, not per node: the map is ordered by gateway first.
  bool have_gateway = false;
  GatewayId gateway = 0;
  bool up = false;
  for (const auto& [key, node] : nodes_) {
    if (!have_gateway || std::get<0>(key) != gateway) {
      have_gateway = true;
      gateway = std::get<0>(key);
      up = link_up(gateway);
    }
    // No toggle bit, except in the bridge's own mark for a state nothing has told.
    const auto unknown = static_cast<std::uint32_t>(canopen::NmtState::unknown);
    const auto state =
        static_cast<canopen::NmtState>(node.nmt_state == unknown ? unknown : node.nmt_state & 0x7F);
    c.add(state, node.lost || !up, node.in_loader);
  }
  return {c.operational, c.pre_operational, c.stopped, c.in_loader, c.lost, c.unknown};
}

}  // namespace canbridge::bridge
