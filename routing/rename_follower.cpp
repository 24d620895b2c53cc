#include "routing/rename_follower.hpp"

namespace canbridge::bridge {

namespace {

RenameFollowed refused(std::string reason) {
  return RenameFollowed{RenameFollowed::Change::refused, std::move(reason)};
}

}  // namespace

RenameFollowed follow_rename(NodeMap& map, NodeEvent& e) {
  const std::size_t m = e.module_index;
  if (m >= map.modules().size()) return {};
  switch (e.kind) {
    case NodeEvent::Kind::booted: {
      const NodeId planned = map.planned_move(m, e.local);
      if (planned == 0) return {};
      map.cancel_move(m, e.local);
      const NodeId old = map.surface_of(m, e.local);
      if (const auto problem = map.move_problem(m, e.local, e.local, planned)) {
        // Taken since the command was checked (another node moved there first).
        return refused("module " + std::to_string(map.modules()[m].id) + " node " +
                       std::to_string(e.local) + " booted, but cannot take surface id " +
                       std::to_string(planned) + ": " + *problem);
      }
      map.move(m, e.local, e.local, planned);
      e.kind = NodeEvent::Kind::renamed;
      e.previous_local = e.local;
      e.previous_surface = old;
      return {RenameFollowed::Change::moved, {}};
    }
    case NodeEvent::Kind::renamed: {
      const NodeId from = e.previous_local;
      e.previous_surface = from != 0 ? map.surface_of(m, from) : NodeId{0};
      if (from != 0) map.cancel_move(m, from);
      map.cancel_move(m, e.local);
      if (map.surface_of(m, e.local) != 0) return {};  // a mapped id: the map has it already
      if (e.previous_surface == 0) {
        return refused("module " + std::to_string(map.modules()[m].id) + " node " +
                       std::to_string(from) + " renamed to " + std::to_string(e.local) +
                       ", which the module does not map, and had no surface id to keep: not "
                       "visible on the surface");
      }
      if (const auto problem = map.move_problem(m, from, e.local, e.previous_surface)) {
        return refused(*problem);
      }
      map.move(m, from, e.local, e.previous_surface);
      return {RenameFollowed::Change::moved, {}};
    }
    case NodeEvent::Kind::rename_unconfirmed:
      if (e.previous_local == e.local) map.cancel_move(m, e.local);
      return {};
    default:
      return {};
  }
}

}  // namespace canbridge::bridge
