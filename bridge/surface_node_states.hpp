// The surface's view of every gateway's nodes, kept from the node events the gateways send: the
// node summary (operational, pre-operational, stopped, in loader, lost) of the surface's
// statistics, and the node list the surface gives for a gateway that is down. Pure: events in,
// counts and nodes out; no clock, no logging.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <tuple>

#include "bridge/role_statistics.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

// A node is known by its gateway, module and local id, the key of the gateway's own node table
// (routing/node_table.hpp): the surface then counts what the gateways count, nodes without a
// surface id included, and a rename moves the node from its previous local id (and with it from
// its previous surface id) to the new one. A node counts once: lost, else in loader, else by its
// NMT state, as NodeTable::counts does.
//
// A gateway's nodes are kept while its link is down, counted as lost: a master on the surface
// bus can reach none of them, so none is operational to the operator, yet the same gateway
// process resumes its reliable stream (with the events it queued meanwhile) when the link
// returns, so their states come back without a new event. A new gateway process (a restart)
// knows none of them: forget() drops them all, and its node table reports each node again as it
// hears it (discovered or booted). The other way round, a gateway sends a new surface process
// (a restarted surface) its whole node table: a DISCOVERED of each node in its present state,
// followed by a LOST for one the table counts lost, behind the events already queued.
class SurfaceNodeStates {
 public:
  using GatewayId = std::uint32_t;  // GatewayTable's id
  using LinkUp = std::function<bool(GatewayId)>;

  // Applies one event of `gateway`. False when it changes nothing the summary could show: a kind
  // this version does not know, a local id outside 1..127, a rename the node table did not
  // confirm (the node has not moved). Memory grows with the (module, local id) pairs seen: the
  // caller passes only events for modules the gateway announced.
  bool apply(GatewayId gateway, const v1::NodeEvent& event);
  // Drops every node of `gateway`: a new process, or a gateway that is gone.
  void forget(GatewayId gateway);
  // Every known node, counted by state; the nodes of a gateway whose link is down count as lost.
  NodeSummary summary(const LinkUp& link_up) const;
  std::size_t size() const { return nodes_.size(); }

  // A node as the gateway's last event described it.
  struct Node {
    std::uint32_t nmt_state = 0;  // CiA 301 heartbeat byte
    bool lost = false;
    bool in_loader = false;
    std::uint32_t surface_node = 0;  // 0: unmapped
    std::uint32_t boot_count = 0;
  };
  // The nodes of `gateway` by module and local id, in that order: what the surface can tell of
  // them while their gateway cannot be asked.
  void for_each_node(GatewayId gateway,
                     const std::function<void(std::uint32_t module_id, std::uint32_t local,
                                              const Node& node)>& f) const;

 private:
  // Gateway, module id, local node id.
  using Key = std::tuple<GatewayId, std::uint32_t, std::uint32_t>;
  std::map<Key, Node> nodes_;
};

}  // namespace canbridge::bridge
