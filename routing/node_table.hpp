// The gateway's table of the nodes on its module buses, kept from their NMT error control frames
// (boot-up, heartbeat, node-guarding replies): which nodes are alive and in which NMT state, how
// often they booted, whether a qd node sits in its loader, and renames by the fpga node-id
// command (docs/nmt-node-id.md). Pure: frames and the time in, events out; no sockets, no timers,
// no logging. The gateway arms one timer at next_deadline() and calls tick() when it fires.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "routing/id_profile.hpp"

namespace canbridge::bridge {

using canopen::NmtState;
using canopen::NodeId;

// Where a qd node runs (seeds/003); other profiles have no loader.
enum class LoaderState : std::uint8_t {
  none,            // cia301 / pdop module: no loader protocol
  in_loader,       // qd: loader boot-up on 0x720 + n seen, no application boot-up since
  in_application,  // qd: application boot-up or heartbeat on 0x700 + n seen since
};

// One node of one module bus, in module-bus terms (local node id).
struct NodeRecord {
  bool known = false;
  // Silent for lost_after: kept in the table with its last state until it is heard again.
  bool lost = false;
  // A heartbeat since the node's last boot-up. Only then is its silence watched: a node whose
  // 1017h is 0 (CANopenNode's default) sends none after its boot-up, answers every SDO and is
  // alive, with no heartbeat to lose; it was reported lost 3 s after every boot.
  bool heartbeat_seen = false;
  // Last NMT state the node reported. A boot-up puts it in pre_operational (CiA 301: the node
  // enters pre-operational autonomously after its boot-up); boot_up only while in the qd loader;
  // unknown for a node known only by an SDO answer or an EMCY (it booted before the gateway
  // started, with its heartbeat off): alive, in a state nothing has told.
  NmtState state = NmtState::boot_up;
  LoaderState loader = LoaderState::none;
  std::uint32_t boot_count = 0;         // application boot-ups (0x700 + n, state 00h)
  std::uint32_t loader_boot_count = 0;  // qd loader boot-ups (0x720 + n)
  std::chrono::steady_clock::time_point last_seen{};
  // The heartbeat period the lost rule uses: the producer time the bridge saw written to the
  // node's 1017h (note_heartbeat_time) since its last boot-up, else the longest of the last
  // kGapWindow gaps between steady heartbeats (same state, the first not itself a state change
  // or a boot-up); zero until one of them is known. Never one gap alone: a device sends one
  // extra heartbeat right after 1017h is written, and that short gap is no period.
  std::chrono::steady_clock::duration interval{0};
  // The producer time last written to 1017h and confirmed by the node; zero: none seen since
  // the node booted (a boot-up restores the node's own default).
  std::chrono::milliseconds heartbeat_time{0};
  std::optional<std::uint32_t> serial;  // 1018h:04, when told by note_serial or a rename
  // The last EMCY (0x080 + n) of a known node: error code and register, and when (nullopt: none
  // since the table knows the node). Kept for the operator's node list (remote access); no event.
  std::uint16_t last_emcy_code = 0;
  std::uint8_t last_emcy_register = 0;
  std::optional<std::chrono::steady_clock::time_point> last_emcy_at;
  // The device type (1000h:00) the node gave in an SDO answer someone read it with (a master at
  // boot, an operator): learnt passively, the gateway never asks the node itself.
  std::optional<std::uint32_t> device_type;
};

struct NodeEvent {
  enum class Kind : std::uint8_t {
    discovered,          // first heartbeat of a node the table had no record of (no boot-up seen)
    booted,              // boot-up on 0x700 + local: the application (re)started
    state_changed,       // a heartbeat reported another NMT state (previous_state -> state)
    lost,                // silent for lost_after; state is the last one reported
    recovered,           // a lost node's heartbeat again; state is the one it reports now
    renamed,             // a node-id command confirmed by the boot-up of `local`; the record of
                         // previous_local (0: unknown, by-serial command) moved there
    rename_unconfirmed,  // no boot-up of `local` within the confirm window; previous_local is
                         // the commanded current id (0 for by-serial unless a record has the
                         // serial)
    loader_booted,       // qd: the loader's boot-up on 0x720 + local
  };
  Kind kind = Kind::booted;
  std::size_t module_index = 0;
  NodeId local = 0;
  NodeId previous_local = 0;  // renamed / rename_unconfirmed only
  // renamed: the surface id the node had, as the gateway's live map knew it before the move
  // (set by follow_rename, rename_follower.hpp; the table works in local ids and leaves it 0).
  NodeId previous_surface = 0;
  NmtState state = NmtState::boot_up;
  NmtState previous_state = NmtState::boot_up;
  std::uint32_t boot_count = 0;
  // The node's serial when known; rename_unconfirmed of a by-serial command: the command's.
  std::optional<std::uint32_t> serial;
  std::chrono::steady_clock::time_point at{};
  friend bool operator==(const NodeEvent&, const NodeEvent&) = default;
};

const char* to_string(NodeEvent::Kind kind);
const char* to_string(LoaderState loader);
// e.g. "module 1 node 9 renamed from 5 (boot 2)": one line for the gateway's log.
std::string to_string(const NodeEvent& event);
// The same with the module's configured id in place of its index: what log lines show, so a
// module carries one number in every line of both roles.
std::string to_string(const NodeEvent& event, std::uint32_t module_id);

// For the periodic stats line. Each known node counts once: lost, else in loader, else by state.
struct NodeCounts {
  std::size_t operational = 0;
  std::size_t pre_operational = 0;
  std::size_t stopped = 0;
  std::size_t in_loader = 0;
  std::size_t lost = 0;
  std::size_t unknown = 0;  // alive (SDO answers, EMCY), state never reported: see NodeRecord
  std::size_t total() const {
    return operational + pre_operational + stopped + in_loader + lost + unknown;
  }
  // Counts one node in its one place (the gateway's table and the surface's view count alike).
  void add(NmtState state, bool is_lost, bool is_in_loader);
  friend bool operator==(const NodeCounts&, const NodeCounts&) = default;
};
// "nodes 7: 5 op, 1 pre-op, 0 stopped, 0 loader, 1 lost" (", 2 unknown" only when there are)
std::string to_string(const NodeCounts& counts);

struct NodeTableOptions {
  // Lost rule without a configured per-module value: 3 x the node's last heartbeat interval,
  // at least min_lost_after; default_lost_after until an interval is known (a node beating
  // slower than that is reported lost once, then recovered, and then keeps its own rule).
  std::chrono::milliseconds min_lost_after{100};
  std::chrono::milliseconds default_lost_after{3000};
  // A node-id command is confirmed by the boot-up of the new id within this window.
  std::chrono::milliseconds rename_confirm_window{2000};
};

class NodeTable {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  using Duration = Clock::duration;
  static constexpr int kLostIntervals = 3;
  // Gaps the measured interval is the longest of.
  static constexpr std::size_t kGapWindow = 4;

  explicit NodeTable(NodeTableOptions options = {});

  // Adds the next module (indices 0, 1, ... in call order: add them in NodeMap::modules() order).
  // `heartbeat_lost_after` (config ModuleOptions::heartbeat_lost_after) overrides the lost rule.
  std::size_t add_module(IdProfile profile,
                         std::optional<std::chrono::milliseconds> heartbeat_lost_after = {});
  std::size_t module_count() const { return modules_.size(); }

  // Every frame read on module `module_index`'s bus. Only NMT error control (0x700..0x77F,
  // standard data frame of exactly 1 byte), EMCY (0x081..0x0FF, at least 3 bytes: kept in the
  // record) and SDO answers (0x581..0x5FF) are looked at; every other frame costs three compares.
  // An EMCY or SDO answer of a node the table does not know (it booted before the gateway, with
  // its heartbeat off) lists it alive in state unknown, not watched; of a lost node, recovers it
  // the same way: it answers, whatever its heartbeat does.
  // A steady heartbeat of a known node in the same state appends nothing and allocates nothing.
  // Events are appended to `out` (never cleared here).
  void on_bus_frame(std::size_t module_index, const can::Frame& frame, TimePoint now,
                    std::vector<NodeEvent>& out);
  // An NMT frame (COB-ID 0) written to module `module_index`'s bus, by the bridge or a local
  // master. Reset node / reset communication: the addressed nodes get default_lost_after to
  // boot before they can be lost. E0h/E1h node-id commands open a pending rename for the new id
  // (replacing a different pending command for that id, which is reported rename_unconfirmed).
  void on_nmt_to_bus(std::size_t module_index, const can::Frame& frame, TimePoint now,
                     std::vector<NodeEvent>& out);
  // The serial number (1018h:04) of a known node, e.g. read by the gateway through SDO: lets a
  // by-serial rename name the id the node had. Another record holding the same serial loses it.
  // False (nothing stored) when the node is not in the table.
  bool note_serial(std::size_t module_index, NodeId local, std::uint32_t serial);
  // The node confirmed a write of `producer_time` to its heartbeat producer time (1017h), seen
  // by the gateway in an SDO transfer from either master: from now on its lost rule uses that
  // period instead of the gaps it measures. 0 turns the node's heartbeat off: it is not watched
  // (never reported lost) until it is heard again. False when the node is not in the table.
  bool note_heartbeat_time(std::size_t module_index, NodeId local,
                           std::chrono::milliseconds producer_time);
  // The gateway found the node waiting in its qd loader (the loader answered its probe of
  // 1F57h:01) without having heard the loader's boot-up: it booted before the gateway started, and
  // a loader sends nothing on its own. Recorded in the loader (not watched, as after a loader
  // boot-up, but with no boot counted) and reported discovered; nothing for a node the table knows
  // from a heartbeat or boot-up (it was heard meanwhile, and that says more). A node known only by
  // its SDO answers (state unknown) may be this very loader answering: it is recorded in it.
  void on_found_in_loader(std::size_t module_index, NodeId local, TimePoint now,
                          std::vector<NodeEvent>& out);

  // Reports the nodes silent for their lost_after (`lost`) and the pending renames whose window
  // ended (`rename_unconfirmed`, before any `lost` of the same tick).
  void tick(TimePoint now, std::vector<NodeEvent>& out);
  // The earliest time at which tick() has something to do; nullopt when nothing is watched (no
  // node alive outside the loader, no pending rename). Exact; cheap unless the earliest
  // deadline moved since the last call (then one pass over the table).
  std::optional<TimePoint> next_deadline() const;

  // nullptr when the table has no record of the node.
  const NodeRecord* node(std::size_t module_index, NodeId local) const;
  // f(NodeId local, const NodeRecord&) for each known node of the module, by ascending id.
  template <class F>
  void for_each_known(std::size_t module_index, F&& f) const {
    if (module_index >= modules_.size()) return;
    const Module& m = modules_[module_index];
    for (NodeId local = 1; local <= m.max_node; ++local) {
      if (m.slots[local].record.known) f(local, m.slots[local].record);
    }
  }
  NodeCounts counts(std::size_t module_index) const;
  NodeCounts counts() const;  // all modules
  // The silence after which the node counts as lost, by the rule above (default_lost_after or
  // the module's value for a node the table does not know).
  Duration lost_after(std::size_t module_index, NodeId local) const;

 private:
  struct Slot {
    NodeRecord record;
    TimePoint deadline = TimePoint::max();  // lost at this time unless heard; max: not watched
    TimePoint hold_until{};                 // not lost before this (reset / rename sent to it)
    bool timing = false;         // the last frame was a steady heartbeat: the next one gives a gap
    bool heartbeat_off = false;  // 1017h written to 0: not watched until heard again
    std::array<Duration, kGapWindow> gaps{};  // the last steady gaps, a ring; zero: none
    std::uint8_t next_gap = 0;
  };
  struct PendingRename {
    bool active = false;
    bool by_serial = false;
    NodeId from = 0;  // E0h: the commanded current id
    std::uint32_t serial = 0;
    TimePoint expires{};
  };
  struct Module {
    IdProfile profile = IdProfile::cia301;
    NodeId max_node = canopen::kMaxNodeId;
    std::optional<Duration> lost_after;
    std::array<Slot, 128> slots{};            // by local node id; 0 unused
    std::array<PendingRename, 32> pending{};  // by new id (1..31, the command's range)
  };

  void on_heartbeat(std::size_t module_index, NodeId local, NmtState state, TimePoint now,
                    std::vector<NodeEvent>& out);
  void on_emcy(std::size_t module_index, const can::Frame& frame, TimePoint now,
               std::vector<NodeEvent>& out);
  // An SDO answer (0x580 + n): the node answers; one carrying 1000h:00 gives its device type.
  void on_sdo_answer(std::size_t module_index, const can::Frame& frame, TimePoint now,
                     std::vector<NodeEvent>& out);
  // A frame only an alive node sends (SDO answer, EMCY) from `local`: listed when unknown,
  // recovered when lost. The record, or nullptr when `local` is no node id of the module.
  NodeRecord* note_answering(std::size_t module_index, NodeId local, TimePoint now,
                             std::vector<NodeEvent>& out);
  void on_boot_up(std::size_t module_index, NodeId local, TimePoint now,
                  std::vector<NodeEvent>& out);
  void on_loader_boot_up(std::size_t module_index, NodeId local, TimePoint now,
                         std::vector<NodeEvent>& out);
  // What an application or loader boot-up does to the node's record: a count (`kind` booted or
  // loader_booted; discovered, for a node found in its loader, counts none), the state, fresh
  // timing, and one event.
  void record_boot(std::size_t module_index, NodeId local, NodeEvent::Kind kind, NmtState state,
                   LoaderState loader, TimePoint now, std::vector<NodeEvent>& out);
  bool confirm_rename(std::size_t module_index, NodeId local, const PendingRename& p, TimePoint now,
                      std::vector<NodeEvent>& out);
  void open_rename(std::size_t module_index, NodeId next, const PendingRename& p, TimePoint now,
                   std::vector<NodeEvent>& out);
  void close_rename(Module& m, NodeId next);
  NodeEvent unconfirmed_event(std::size_t module_index, NodeId next, const PendingRename& p,
                              TimePoint now) const;
  void hold(Module& m, NodeId local, TimePoint until);
  // Forgets the measured gaps (an outage, a boot-up: the next period is measured afresh).
  static void forget_gaps(Slot& s);
  // record.interval from the configured producer time or the measured gaps.
  static void update_interval(Slot& s);
  NodeId find_serial(const Module& m, std::uint32_t serial) const;  // 0: none
  Duration lost_after(const Module& m, const NodeRecord& r) const;
  TimePoint due(const Module& m, const Slot& s) const;
  void set_deadline(Slot& s, TimePoint deadline);
  void deadline_moved(TimePoint from, TimePoint to);
  TimePoint scan_earliest() const;
  static NodeEvent event(NodeEvent::Kind kind, std::size_t module_index, NodeId local,
                         const NodeRecord& r, TimePoint now);

  Duration min_lost_after_;
  Duration default_lost_after_;
  Duration confirm_window_;
  std::vector<Module> modules_;
  // The earliest deadline of slots and pending renames; when dirty, recomputed by one scan.
  mutable TimePoint earliest_ = TimePoint::max();
  mutable bool earliest_dirty_ = false;
};

}  // namespace canbridge::bridge
