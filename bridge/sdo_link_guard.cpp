#include "bridge/sdo_link_guard.hpp"

namespace canbridge::bridge {

canopen::NodeId SdoLinkGuard::request_node(const can::Frame& frame) {
  if (frame.is_extended() || frame.is_remote() || frame.len != 8) return 0;
  if (frame.id <= canopen::cob::sdo_rx || frame.id > canopen::cob::sdo_rx + canopen::kMaxNodeId) {
    return 0;
  }
  return static_cast<canopen::NodeId>(frame.id - canopen::cob::sdo_rx);
}

can::Frame SdoLinkGuard::abort_for(canopen::NodeId node, const Node& n) {
  return can::Frame::standard(
      canopen::cob::sdo_tx + node,
      {0x80, n.mux[0], n.mux[1], n.mux[2], static_cast<std::uint8_t>(kLinkDownAbort),
       static_cast<std::uint8_t>(kLinkDownAbort >> 8),
       static_cast<std::uint8_t>(kLinkDownAbort >> 16),
       static_cast<std::uint8_t>(kLinkDownAbort >> 24)});
}

bool SdoLinkGuard::on_gateway_frame(GatewayId gateway, const can::Frame& frame) {
  if (frame.is_extended()) return true;
  const auto address = canopen::split_predefined(frame.id);
  if (!address || address->node == 0) return true;
  Node& n = nodes_[address->node];
  n.owned = true;
  n.gateway = gateway;
  if (address->function_base != canopen::cob::sdo_tx) return true;
  if (n.aborted && !n.pending) {
    ++counters_.late_responses_dropped;
    return false;
  }
  n.pending = false;
  return true;
}

void SdoLinkGuard::note_owner(GatewayId gateway, canopen::NodeId node) {
  if (node == 0 || node > canopen::kMaxNodeId) return;
  nodes_[node].owned = true;
  nodes_[node].gateway = gateway;
}

void SdoLinkGuard::note_claims(GatewayId gateway, const GatewayClaims& claims) {
  for (const ModuleClaim& m : claims.modules) {
    for (canopen::NodeId node : m.surface_nodes) note_owner(gateway, node);
  }
}

std::optional<can::Frame> SdoLinkGuard::on_not_forwarded(const can::Frame& frame) {
  const canopen::NodeId node = request_node(frame);
  if (node == 0 || frame.data[0] >> 5 == 4) return std::nullopt;  // not a request, or an abort
  Node& n = nodes_[node];
  n.pending = false;
  n.aborted = true;
  ++counters_.aborted_not_forwarded;
  return abort_for(node, n);
}

std::vector<can::Frame> SdoLinkGuard::on_gateway_down(GatewayId gateway) {
  std::vector<can::Frame> aborts;
  for (canopen::NodeId node = 1; node <= canopen::kMaxNodeId; ++node) {
    Node& n = nodes_[node];
    if (!n.owned || n.gateway != gateway || !n.pending) continue;
    n.pending = false;
    n.aborted = true;
    ++counters_.aborted_in_flight;
    aborts.push_back(abort_for(node, n));
  }
  return aborts;
}

std::optional<can::Frame> SdoLinkGuard::on_request_discarded(const can::Frame& request) {
  const canopen::NodeId node = request_node(request);
  if (node == 0) return std::nullopt;
  const std::uint8_t command = request.data[0] >> 5;
  if (command == 4) return std::nullopt;  // the master's own abort needs no answer
  Node& n = nodes_[node];
  if (n.owned && !n.pending) return std::nullopt;  // answered already
  Node answer = n;
  if (!n.owned && (command == 1 || command == 2 || command == 5 || command == 6)) {
    answer.mux[0] = request.data[1];
    answer.mux[1] = request.data[2];
    answer.mux[2] = request.data[3];
  }
  n.pending = false;
  n.aborted = n.owned;
  ++counters_.aborted_discarded;
  return abort_for(node, answer);
}

std::optional<SdoLinkGuard::GatewayId> SdoLinkGuard::owner_of(canopen::NodeId node) const {
  if (node == 0 || node > canopen::kMaxNodeId || !nodes_[node].owned) return std::nullopt;
  return nodes_[node].gateway;
}

}  // namespace canbridge::bridge
