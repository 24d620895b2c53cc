#include "bridge/gateway_node_events.hpp"

#include <spdlog/spdlog.h>

#include "bridge/gateway_claims.hpp"
#include "bridge/node_event_text.hpp"
#include "routing/rename_follower.hpp"

namespace canbridge::bridge {

GatewayNodeEvents::GatewayNodeEvents(std::string gateway_name, NodeMap& map,
                                     std::vector<ModuleId> module_ids, OnNodeMoved on_node_moved)
    : name_(std::move(gateway_name)),
      map_(map),
      module_ids_(std::move(module_ids)),
      on_node_moved_(std::move(on_node_moved)) {}

void GatewayNodeEvents::follow_renames() {
  for (; followed_ < events_.size(); ++followed_) {
    NodeEvent& e = events_[followed_];
    const RenameFollowed followed = follow_rename(map_, e);
    if (followed.change == RenameFollowed::Change::moved) {
      ++counters_.nodes_moved;
      claims_changed_ = true;
      spdlog::info("gateway {}: module {} node {} now has surface id {} (was {})", name_,
                   module_ids_[e.module_index], e.local, map_.surface_of(e.module_index, e.local),
                   e.previous_surface);
      if (on_node_moved_) on_node_moved_(e.module_index);
    } else if (followed.change == RenameFollowed::Change::refused) {
      ++counters_.node_moves_refused;
      warn_.warn(Warn::kRenameRefused,
                 "gateway {}: rename not followed in the node map: {} "
                 "(counted; later ones only in the counters)",
                 name_, followed.reason);
    }
  }
}

void GatewayNodeEvents::on_rename_refused(const RenameRefusal& refusal, const NodeTable& table,
                                          NodeTable::Clock::time_point now) {
  warn_.warn(Warn::kRenameRefused,
             "gateway {}: {}: refused (counted as rename-refused; later ones only counted)", name_,
             refusal.reason);
  if (!refusal.node) return;
  NodeEvent e;
  e.kind = NodeEvent::Kind::rename_unconfirmed;
  e.module_index = refusal.node->module_index;
  e.local = refusal.node->local;
  e.at = now;
  if (const NodeRecord* record = table.node(e.module_index, e.local)) {
    e.state = record->state;
    e.boot_count = record->boot_count;
  }
  events_.push_back(e);
}

std::optional<std::string> GatewayNodeEvents::settle() {
  follow_renames();
  for (const NodeEvent& e : events_) {
    spdlog::info("gateway {}: {}", name_, to_string(e, module_ids_[e.module_index]));
    hint_loader_boot_on_cia301(e);
  }
  if (!claims_changed_ || events_.empty()) return std::nullopt;
  // A node moved in the live map: the surface routes its new surface id here from now on.
  claims_changed_ = false;
  return encode_claims(claims_of(map_));
}

void GatewayNodeEvents::clear() {
  events_.clear();
  followed_ = 0;
}

void GatewayNodeEvents::hint_loader_boot_on_cia301(const NodeEvent& e) {
  // qd puts node n's loader boot-up on 0x720 + n: read as CiA 301, that is a boot-up of node
  // 32 + n, which no module of at most 31 nodes maps.
  constexpr NodeId kLoaderBase = 0x20;
  if (e.kind != NodeEvent::Kind::booted || e.local <= kLoaderBase || e.local >= 2 * kLoaderBase ||
      map_.modules()[e.module_index].profile != IdProfile::cia301 ||
      map_.surface_of(e.module_index, e.local) != 0) {
    return;
  }
  // A hint, not a warning: a CiA 301 module may carry qd nodes among others (the demo does), whose
  // applications work there and whose loaders are then simply not reachable.
  warn_.hint(Warn::kLoaderBootOnCia301,
             "gateway {}: module {}: a boot-up on 0x{:03X} (node {}) has no surface id: most "
             "likely node {}'s qd loader announcing itself (0x720 + node id), which a cia301 "
             "module does not map; to reach the loaders of a module of qd nodes, set 'profile: "
             "qd' for it (said once; later ones counted as untranslatable)",
             name_, module_ids_[e.module_index], 0x700u + e.local, e.local, e.local - kLoaderBase);
}

}  // namespace canbridge::bridge
