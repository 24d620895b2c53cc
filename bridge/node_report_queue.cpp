#include "bridge/node_report_queue.hpp"

#include <algorithm>

namespace canbridge::bridge {

namespace {

v1::NodeEvent::Kind to_proto(NodeEvent::Kind kind) {
  switch (kind) {
    case NodeEvent::Kind::discovered:
      return v1::NodeEvent::DISCOVERED;
    case NodeEvent::Kind::booted:
      return v1::NodeEvent::BOOTED;
    case NodeEvent::Kind::state_changed:
      return v1::NodeEvent::STATE_CHANGED;
    case NodeEvent::Kind::lost:
      return v1::NodeEvent::LOST;
    case NodeEvent::Kind::recovered:
      return v1::NodeEvent::RECOVERED;
    case NodeEvent::Kind::renamed:
      return v1::NodeEvent::RENAMED;
    case NodeEvent::Kind::rename_unconfirmed:
      return v1::NodeEvent::RENAME_UNCONFIRMED;
    case NodeEvent::Kind::loader_booted:
      return v1::NodeEvent::LOADER_BOOTED;
  }
  return v1::NodeEvent::KIND_UNSPECIFIED;
}

}  // namespace

NodeReportQueue::NodeReportQueue(const NodeMap& map, const NodeTable& table,
                                 std::vector<ModuleId> module_ids, std::size_t max_payloads)
    : map_(&map),
      table_(&table),
      module_ids_(std::move(module_ids)),
      max_payloads_(std::max<std::size_t>(max_payloads, 1)) {}

void NodeReportQueue::describe(std::size_t m, NodeId local, NmtState state,
                               std::uint32_t boot_count, v1::NodeEvent& out) const {
  out.set_module_id(module_ids_[m]);
  out.set_local_node(local);
  out.set_surface_node(map_->surface_of(m, local));
  out.set_nmt_state(static_cast<std::uint32_t>(state));
  out.set_boot_count(boot_count);
  const NodeRecord* record = table_->node(m, local);
  out.set_in_loader(record && record->loader == LoaderState::in_loader);
}

bool NodeReportQueue::make_room() {
  // The oldest go first: the surface learns the current state from the next events and from the
  // heartbeats.
  if (queue_.size() < max_payloads_) return false;
  const auto oldest =
      std::find_if(queue_.begin(), queue_.end(), [](const Queued& q) { return !q.snapshot; });
  if (oldest == queue_.end()) return false;
  counters_.events_dropped += oldest->events;
  queue_.erase(oldest);
  return true;
}

bool NodeReportQueue::queue_events(std::span<const NodeEvent> events, const std::string& claims) {
  if (events.empty()) return false;
  v1::Payload payload;
  v1::NodeEvents& out = *payload.mutable_node_events();
  if (!claims.empty()) out.mutable_claims()->ParseFromString(claims);
  for (const NodeEvent& e : events) {
    const std::size_t m = e.module_index;
    v1::NodeEvent& o = *out.add_events();
    describe(m, e.local, e.state, e.boot_count, o);
    o.set_kind(to_proto(e.kind));
    o.set_previous_local_node(e.previous_local);
    o.set_previous_surface_node(e.previous_surface ? e.previous_surface
                                : e.previous_local ? map_->surface_of(m, e.previous_local)
                                                   : 0);
  }
  counters_.events += events.size();
  const bool dropped = make_room();
  queue_.push_back({payload.SerializeAsString(), events.size()});
  return dropped;
}

NodeReportQueue::Snapshot NodeReportQueue::queue_snapshot() {
  std::erase_if(queue_, [](const Queued& q) { return q.snapshot; });
  Snapshot s;
  // One payload per module: each stays far below one write (at most 2 x 127 small events).
  for (std::size_t m = 0; m < module_ids_.size(); ++m) {
    v1::Payload payload;
    v1::NodeEvents& out = *payload.mutable_node_events();
    table_->for_each_known(m, [&](NodeId local, const NodeRecord& record) {
      // What the discovery of the node in its present state says; a lost node is then lost, as
      // the surface counts a LOST after it (the last state kept, as in the table).
      v1::NodeEvent& o = *out.add_events();
      describe(m, local, record.state, record.boot_count, o);
      o.set_kind(v1::NodeEvent::DISCOVERED);
      ++s.nodes;
      if (record.lost) {
        v1::NodeEvent& l = *out.add_events();
        l = o;
        l.set_kind(v1::NodeEvent::LOST);
        ++s.lost;
      }
    });
    if (out.events_size() == 0) continue;
    const auto events = static_cast<std::size_t>(out.events_size());
    counters_.events += events;
    if (make_room()) s.dropped = true;
    queue_.push_back({payload.SerializeAsString(), events, true});
  }
  return s;
}

}  // namespace canbridge::bridge
