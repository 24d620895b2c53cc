// The gateway's node events of the input being handled, before they go to the surface: renames
// the node table confirmed are followed in the live map (and the gateway's claims re-encoded), a
// set-node-id command the translator refused becomes a RENAME_UNCONFIRMED event, and a qd
// loader's boot-up on a cia301 module gets the hint of what it probably is. No I/O, no clock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "bridge/warn_once.hpp"
#include "routing/cob_id_translator.hpp"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

class GatewayNodeEvents {
 public:
  struct Counters {
    std::uint64_t nodes_moved = 0;         // renames followed in the live map
    std::uint64_t node_moves_refused = 0;  // confirmed renames the map could not follow
  };
  // Module `m`'s node moved to another surface id (its PDO Packet relay must learn it).
  using OnNodeMoved = std::function<void(std::size_t module_index)>;

  // `module_ids`: the modules of `map`, in its order, for the logs. `map` outlives this.
  GatewayNodeEvents(std::string gateway_name, NodeMap& map, std::vector<ModuleId> module_ids,
                    OnNodeMoved on_node_moved);

  // Where the node table writes its events (NodeTable::on_bus_frame, tick, ...).
  std::vector<NodeEvent>& sink() { return events_; }
  std::span<const NodeEvent> events() const { return events_; }
  bool empty() const { return events_.empty(); }

  // Moves the renamed nodes of the events not yet followed in the live map: called after every
  // frame, so the frame that confirmed a rename already crosses under the node's new surface id.
  void follow_renames();
  // The translator refused a set-node-id command: said once, and when the map has the commanded
  // node a RENAME_UNCONFIRMED event of it joins the events, with its state in `table` now.
  void on_rename_refused(const RenameRefusal& refusal, const NodeTable& table,
                         NodeTable::Clock::time_point now);

  // Follows what is left, logs every event (at info: a node event is rare and an operator's
  // business) with the hint for a loader's boot-up, and returns the claims to send with them when
  // a node moved since the last time (the next hello carries the same), else nothing.
  std::optional<std::string> settle();
  // The events went to the surface: the next input starts empty.
  void clear();

  const Counters& counters() const noexcept { return counters_; }

 private:
  // A boot-up that looks like a qd loader's (0x720 + n) on a module configured as cia301: says
  // once what it probably is, instead of leaving an unmapped node 32 + n in the table unexplained.
  void hint_loader_boot_on_cia301(const NodeEvent& e);

  enum Warn : std::size_t { kRenameRefused, kLoaderBootOnCia301, kWarnKinds };

  std::string name_;
  NodeMap& map_;
  std::vector<ModuleId> module_ids_;
  OnNodeMoved on_node_moved_;
  std::vector<NodeEvent> events_;
  std::size_t followed_ = 0;     // events_[0, this) went through follow_rename
  bool claims_changed_ = false;  // a node moved: the next events carry the new claims
  Counters counters_;
  WarnOnce<kWarnKinds> warn_;
};

}  // namespace canbridge::bridge
