// The gateway's per-module SDO tracking: follows every node's default SDO channel on every module
// bus so that values naming COB-IDs or node ids speak surface ids to the master and module-bus ids
// to the node, and decides which SDO requests waiting for a bus die with the link. Pure: frames
// in, frames rewritten in place, counters; no bus, no link, no clock.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "can/frame.hpp"
#include "canopen/sdo_transaction_tracker.hpp"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

class ModuleSdoTracking {
 public:
  struct Counters {
    // SDO values naming COB-IDs or node ids (1200h.., 1400h.., 1800h.., 1014h, 1016h, 1028h)
    // rewritten between bus and surface ids, and those whose id has no counterpart (forwarded
    // unchanged).
    std::uint64_t values_rewritten = 0;
    std::uint64_t values_unmapped = 0;
    // SDO requests from the surface still waiting for a bus when the link died (the master was
    // told they failed): never written.
    std::uint64_t requests_withdrawn = 0;
  };

  // A heartbeat producer time (1017h sub 0) a node confirmed writing: the node table watches
  // the node with it rather than with gaps it measured (issue 14: never one gap).
  struct HeartbeatWrite {
    canopen::NodeId node = 0;  // module-bus id
    std::chrono::milliseconds period{0};
    friend bool operator==(const HeartbeatWrite&, const HeartbeatWrite&) = default;
  };

  // One channel per node of each module of `map`, which must outlive this. The map is read at
  // each frame, not copied: a node renamed in the live map is rewritten under its new ids.
  explicit ModuleSdoTracking(const NodeMap& map);

  // Bus -> surface. `bus_frame` was read on module `module_index`'s bus and `to_surface` is its
  // translation for the surface (COB-ID already mapped). A node's SDO response has its value
  // rewritten in `to_surface`; a request from a master on the module bus is only followed (its
  // transfer's frames are the node's to answer, and nothing of it is rewritten). Returns the
  // heartbeat period the node's response confirmed writing, if it did.
  std::optional<HeartbeatWrite> from_bus(std::size_t module_index, const can::Frame& bus_frame,
                                         can::Frame& to_surface);

  // Surface -> bus. `frame` is already translated for module `module_index`'s bus; an SDO
  // request to a node of the module has its value rewritten in place.
  void to_bus(std::size_t module_index, can::Frame& frame);

  // A node that booted or was renamed starts with no SDO transfer open: its channel (and the
  // one of its previous id) starts over.
  void on_node_event(const NodeEvent& event);

  // The surface declared the link dead and told the master that every transfer in flight
  // failed: whatever the nodes still send belongs to no transfer, so every channel starts over.
  // The shell then withdraws what withdrawn_at_link_loss() names and reports it (withdrew()).
  void on_link_dead();
  // A frame waiting for a module bus that must never be written once the link died: an SDO
  // request (the master got its abort; executing it later would contradict that).
  static bool withdrawn_at_link_loss(const can::Frame& waiting);
  void withdrew(std::size_t requests) { counters_.requests_withdrawn += requests; }

  const Counters& counters() const { return counters_; }
  // A master's SDO transfer with node `local` of the module is open (a request seen, its end
  // not yet): the gateway's own transfer with the node waits (docs/remote-access.md).
  bool transfer_open(std::size_t module_index, canopen::NodeId local) const {
    return local < 128 && !trackers_[module_index][local].idle();
  }

 private:
  // Default SDO channel of a node of `module_index`: the node id if `frame` is its request
  // (0x600 + n, base sdo_rx) or response (0x580 + n, base sdo_tx) under the module's profile,
  // else 0.
  canopen::NodeId sdo_node(std::size_t module_index, const can::Frame& frame,
                           std::uint16_t base) const;
  void count(canopen::sdo::ValueRewrite rewrite);

  const NodeMap* map_;
  // Per module (the map's order): the id mappings values are rewritten with, and one tracker
  // per node's default SDO channel, which knows the object of every frame of a transfer.
  std::vector<canopen::sdo::IdMapping> to_local_, to_surface_;
  std::vector<std::array<canopen::sdo::ValueTransferTracker, 128>> trackers_;
  Counters counters_;
};

}  // namespace canbridge::bridge
