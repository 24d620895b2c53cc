#include "bridge/module_sdo_tracking.hpp"

#include "bridge/frame_outbox.hpp"

namespace canbridge::bridge {

namespace {

// A value may only name the module's own ids: a COB-ID or node of another bus is not something
// the node can reach.
canopen::sdo::IdMapping to_local_of(const NodeMap* map, std::size_t m) {
  return {[map, m](std::uint32_t cob) -> std::optional<std::uint32_t> {
            auto owner = map->owner_of_surface_cob(cob);
            if (!owner || owner->module_index != m) return std::nullopt;
            return owner->local_cob;
          },
          [map, m](canopen::NodeId node) -> std::optional<canopen::NodeId> {
            auto owner = map->owner_of_surface(node);
            if (!owner || owner->module_index != m) return std::nullopt;
            return owner->local;
          }};
}

canopen::sdo::IdMapping to_surface_of(const NodeMap* map, std::size_t m) {
  return {[map, m](std::uint32_t cob) -> std::optional<std::uint32_t> {
            const std::uint16_t surface = map->surface_cob_of(m, cob);
            if (surface == 0) return std::nullopt;
            return surface;
          },
          [map, m](canopen::NodeId node) -> std::optional<canopen::NodeId> {
            const canopen::NodeId surface = map->surface_of(m, node);
            if (surface == 0) return std::nullopt;
            return surface;
          }};
}

}  // namespace

ModuleSdoTracking::ModuleSdoTracking(const NodeMap& map)
    : map_(&map), trackers_(map.modules().size()) {
  for (std::size_t m = 0; m < map.modules().size(); ++m) {
    to_local_.push_back(to_local_of(map_, m));
    to_surface_.push_back(to_surface_of(map_, m));
  }
}

std::optional<ModuleSdoTracking::HeartbeatWrite> ModuleSdoTracking::from_bus(
    std::size_t m, const can::Frame& bus_frame, can::Frame& to_surface) {
  if (const canopen::NodeId node = sdo_node(m, bus_frame, canopen::cob::sdo_tx)) {
    auto& tracker = trackers_[m][node];
    count(tracker.on_response(to_surface, to_surface_[m]));
    if (const auto& w = tracker.confirmed_write(); w && w->mux.index == 0x1017 && w->mux.sub == 0) {
      return HeartbeatWrite{node, std::chrono::milliseconds(w->value & 0xFFFF)};
    }
  } else if (const canopen::NodeId client = sdo_node(m, bus_frame, canopen::cob::sdo_rx)) {
    // A master on the module bus: its writes are seen, its transfer's frames followed.
    can::Frame observed = bus_frame;
    trackers_[m][client].on_request(observed, {});
  }
  return std::nullopt;
}

void ModuleSdoTracking::to_bus(std::size_t m, can::Frame& frame) {
  if (const canopen::NodeId node = sdo_node(m, frame, canopen::cob::sdo_rx)) {
    count(trackers_[m][node].on_request(frame, to_local_[m]));
  }
}

void ModuleSdoTracking::on_node_event(const NodeEvent& e) {
  if (e.kind != NodeEvent::Kind::booted && e.kind != NodeEvent::Kind::renamed &&
      e.kind != NodeEvent::Kind::loader_booted) {
    return;
  }
  auto& module = trackers_[e.module_index];
  module[e.local].reset();
  if (e.previous_local != 0) module[e.previous_local].reset();
}

void ModuleSdoTracking::on_link_dead() {
  for (auto& module : trackers_) {
    for (auto& tracker : module) tracker.reset();
  }
}

bool ModuleSdoTracking::withdrawn_at_link_loss(const can::Frame& waiting) {
  return is_sdo_request(waiting);
}

canopen::NodeId ModuleSdoTracking::sdo_node(std::size_t m, const can::Frame& frame,
                                            std::uint16_t base) const {
  if (frame.is_extended() || frame.id <= base) return 0;
  const std::uint32_t node = frame.id - base;
  return node <= max_node_id(map_->modules()[m].profile) ? static_cast<canopen::NodeId>(node)
                                                         : canopen::NodeId{0};
}

void ModuleSdoTracking::count(canopen::sdo::ValueRewrite rewrite) {
  if (rewrite == canopen::sdo::ValueRewrite::rewritten) ++counters_.values_rewritten;
  if (rewrite == canopen::sdo::ValueRewrite::no_counterpart) ++counters_.values_unmapped;
}

}  // namespace canbridge::bridge
