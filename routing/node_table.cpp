#include "routing/node_table.hpp"

#include <algorithm>
#include <cstdio>

#include "canopen/nmt_node_id.hpp"

namespace canbridge::bridge {

namespace {

constexpr std::uint32_t kNodeBits = 0x7F;  // bits 6-0 of an error control COB-ID
constexpr std::uint8_t kToggleBit = 0x80;  // node-guarding reply toggle, byte 0 bit 7
constexpr NodeId kLoaderSlot = 1;          // qd: 0x720 + n is the loader's boot-up
constexpr std::uint8_t kSlotShift = 5;     // pdop / qd: slot bits 6-5, node bits 4-0
constexpr std::uint8_t kSlotNodeMask = 0x1F;

std::string hex32(std::uint32_t value) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%08X", static_cast<unsigned>(value));
  return text;
}

}  // namespace

const char* to_string(NodeEvent::Kind kind) {
  switch (kind) {
    case NodeEvent::Kind::discovered:
      return "discovered";
    case NodeEvent::Kind::booted:
      return "booted";
    case NodeEvent::Kind::state_changed:
      return "state_changed";
    case NodeEvent::Kind::lost:
      return "lost";
    case NodeEvent::Kind::recovered:
      return "recovered";
    case NodeEvent::Kind::renamed:
      return "renamed";
    case NodeEvent::Kind::rename_unconfirmed:
      return "rename_unconfirmed";
    case NodeEvent::Kind::loader_booted:
      return "loader_booted";
  }
  return "?";
}

const char* to_string(LoaderState loader) {
  switch (loader) {
    case LoaderState::none:
      return "none";
    case LoaderState::in_loader:
      return "in loader";
    case LoaderState::in_application:
      return "in application";
  }
  return "?";
}

std::string to_string(const NodeEvent& e, std::uint32_t module_id) {
  NodeEvent named = e;
  named.module_index = module_id;
  return to_string(named);
}

std::string to_string(const NodeEvent& e) {
  std::string s = "module " + std::to_string(e.module_index) + " node " + std::to_string(e.local);
  const std::string boot = "boot " + std::to_string(e.boot_count);
  switch (e.kind) {
    case NodeEvent::Kind::discovered:
      return s + " discovered (" + canopen::nmt_state_name(static_cast<std::uint32_t>(e.state)) +
             ")";
    case NodeEvent::Kind::booted:
      return s + " booted (" + boot + ")";
    case NodeEvent::Kind::state_changed:
      return s + " " + canopen::nmt_state_name(static_cast<std::uint32_t>(e.previous_state)) +
             " -> " + canopen::nmt_state_name(static_cast<std::uint32_t>(e.state));
    case NodeEvent::Kind::lost:
      return s + " lost (was " + canopen::nmt_state_name(static_cast<std::uint32_t>(e.state)) + ")";
    case NodeEvent::Kind::recovered:
      return s + " recovered (" + canopen::nmt_state_name(static_cast<std::uint32_t>(e.state)) +
             ")";
    case NodeEvent::Kind::renamed:
      s += e.previous_local != 0 ? " renamed from " + std::to_string(e.previous_local)
                                 : std::string(" renamed from an unknown id");
      if (e.serial) s += ", serial " + hex32(*e.serial);
      return s + " (" + boot + ")";
    case NodeEvent::Kind::rename_unconfirmed:
      s += " not confirmed by a boot-up: node-id command";
      if (e.previous_local != 0) s += " from node " + std::to_string(e.previous_local);
      if (e.serial) s += " for serial " + hex32(*e.serial);
      return s;
    case NodeEvent::Kind::loader_booted:
      return s + " loader booted";
  }
  return s;
}

std::string to_string(const NodeCounts& c) {
  return "nodes " + std::to_string(c.total()) + ": " + std::to_string(c.operational) + " op, " +
         std::to_string(c.pre_operational) + " pre-op, " + std::to_string(c.stopped) +
         " stopped, " + std::to_string(c.in_loader) + " loader, " + std::to_string(c.lost) +
         " lost" + (c.unknown != 0 ? ", " + std::to_string(c.unknown) + " unknown" : "");
}

NodeTable::NodeTable(NodeTableOptions options)
    : min_lost_after_(options.min_lost_after),
      default_lost_after_(options.default_lost_after),
      confirm_window_(options.rename_confirm_window) {
  min_lost_after_ = std::min(min_lost_after_, default_lost_after_);
}

std::size_t NodeTable::add_module(IdProfile profile,
                                  std::optional<std::chrono::milliseconds> heartbeat_lost_after) {
  Module m;
  m.profile = profile;
  m.max_node = max_node_id(profile);
  if (heartbeat_lost_after) m.lost_after = Duration(*heartbeat_lost_after);
  modules_.push_back(m);
  return modules_.size() - 1;
}

void NodeTable::on_bus_frame(std::size_t module_index, const can::Frame& frame, TimePoint now,
                             std::vector<NodeEvent>& out) {
  // The one branch every frame other than NMT error control (0x700..0x77F) takes, plus one.
  if ((frame.id & ~kNodeBits) != canopen::cob::heartbeat) {
    if ((frame.id & ~kNodeBits) == canopen::cob::emcy) on_emcy(module_index, frame, now, out);
    if ((frame.id & ~kNodeBits) == canopen::cob::sdo_tx) {
      on_sdo_answer(module_index, frame, now, out);
    }
    return;
  }
  // Extended, remote (a master's node-guarding request) and error frames have flags.
  if (!frame.is_standard_data() || frame.len != 1 || module_index >= modules_.size()) return;
  const Module& m = modules_[module_index];
  auto local = static_cast<NodeId>(frame.id & kNodeBits);
  const std::uint8_t byte = frame.data[0];
  if (m.profile != IdProfile::cia301) {
    const auto slot = static_cast<NodeId>(local >> kSlotShift);
    local &= kSlotNodeMask;
    if (slot == kLoaderSlot && m.profile == IdProfile::qd) {
      if (local != 0 && byte == 0x00) on_loader_boot_up(module_index, local, now, out);
      return;
    }
    if (slot != 0) return;  // no node's error control on a pdop / qd bus
  }
  if (local == 0) return;
  const auto state = static_cast<std::uint8_t>(byte & ~kToggleBit);
  switch (state) {
    case static_cast<std::uint8_t>(NmtState::boot_up):
      // A node-guarding reply never reports boot-up: 80h is no valid error control byte.
      if (byte == 0x00) on_boot_up(module_index, local, now, out);
      return;
    case static_cast<std::uint8_t>(NmtState::stopped):
    case static_cast<std::uint8_t>(NmtState::operational):
    case static_cast<std::uint8_t>(NmtState::pre_operational):
      on_heartbeat(module_index, local, static_cast<NmtState>(state), now, out);
      return;
    default:
      return;
  }
}

NodeRecord* NodeTable::note_answering(std::size_t module_index, NodeId local, TimePoint now,
                                      std::vector<NodeEvent>& out) {
  Module& m = modules_[module_index];
  // pdop / qd: slot 0 of nodes 1..31 (bits 6-5 name other objects).
  if (local == 0 || local > m.max_node) return nullptr;
  Slot& s = m.slots[local];
  NodeRecord& r = s.record;
  if (r.known && !r.lost) {
    if (!r.heartbeat_seen) r.last_seen = now;
    return &r;
  }
  const bool was_lost = r.lost;
  if (!r.known) {
    r = NodeRecord{};
    r.known = true;
    r.state = NmtState::unknown;
  }
  // Alive with no heartbeat to watch: watched again from its next heartbeat.
  r.lost = false;
  r.heartbeat_seen = false;
  r.last_seen = now;
  forget_gaps(s);
  s.timing = false;
  set_deadline(s, TimePoint::max());
  out.push_back(event(was_lost ? NodeEvent::Kind::recovered : NodeEvent::Kind::discovered,
                      module_index, local, r, now));
  return &r;
}

void NodeTable::on_sdo_answer(std::size_t module_index, const can::Frame& frame, TimePoint now,
                              std::vector<NodeEvent>& out) {
  // Any SDO server frame has 8 bytes (CiA 301); a shorter one is some other use of the id.
  if (!frame.is_standard_data() || frame.len != 8 || module_index >= modules_.size()) return;
  const auto local = static_cast<NodeId>(frame.id & kNodeBits);
  NodeRecord* r = note_answering(module_index, local, now, out);
  // Only an expedited upload answer of 4 bytes (43h) for 1000h:00: the device type.
  if (r == nullptr || frame.data[0] != 0x43 || frame.data[1] != 0x00 || frame.data[2] != 0x10 ||
      frame.data[3] != 0x00) {
    return;
  }
  r->device_type =
      static_cast<std::uint32_t>(frame.data[4] | (frame.data[5] << 8) | (frame.data[6] << 16) |
                                 (static_cast<std::uint32_t>(frame.data[7]) << 24));
}

void NodeTable::on_emcy(std::size_t module_index, const can::Frame& frame, TimePoint now,
                        std::vector<NodeEvent>& out) {
  if (!frame.is_standard_data() || frame.len < 3 || module_index >= modules_.size()) return;
  const auto local = static_cast<NodeId>(frame.id & kNodeBits);
  NodeRecord* r = note_answering(module_index, local, now, out);
  if (r == nullptr) return;
  r->last_emcy_code = static_cast<std::uint16_t>(frame.data[0] | (frame.data[1] << 8));
  r->last_emcy_register = frame.data[2];
  r->last_emcy_at = now;
}

void NodeTable::on_heartbeat(std::size_t module_index, NodeId local, NmtState state, TimePoint now,
                             std::vector<NodeEvent>& out) {
  Module& m = modules_[module_index];
  Slot& s = m.slots[local];
  NodeRecord& r = s.record;
  const LoaderState loader =
      m.profile == IdProfile::qd ? LoaderState::in_application : LoaderState::none;
  s.heartbeat_off = false;
  if (!r.known) {
    r = NodeRecord{};
    r.known = true;
    r.heartbeat_seen = true;
    r.state = state;
    r.loader = loader;
    r.last_seen = now;
    forget_gaps(s);
    s.timing = true;
    set_deadline(s, due(m, s));
    out.push_back(event(NodeEvent::Kind::discovered, module_index, local, r, now));
    return;
  }
  const NmtState previous = r.state;
  const bool was_lost = r.lost;
  if (was_lost) {
    // The silence was an outage, not a period: measure afresh.
    r.lost = false;
    forget_gaps(s);
    update_interval(s);
    s.timing = state == previous;
  } else if (state == previous) {
    if (s.timing && now > r.last_seen) {
      s.gaps[s.next_gap] = now - r.last_seen;
      s.next_gap = static_cast<std::uint8_t>((s.next_gap + 1) % kGapWindow);
      update_interval(s);
    }
    s.timing = true;
  } else {
    // Many stacks send a heartbeat at once on a state change, off their period.
    s.timing = false;
  }
  r.state = state;
  r.loader = loader;
  r.last_seen = now;
  r.heartbeat_seen = true;
  set_deadline(s, due(m, s));
  if (!was_lost && state == previous) return;  // the common path: no event, no allocation
  NodeEvent e = event(was_lost ? NodeEvent::Kind::recovered : NodeEvent::Kind::state_changed,
                      module_index, local, r, now);
  e.previous_state = previous;
  out.push_back(e);
}

void NodeTable::on_boot_up(std::size_t module_index, NodeId local, TimePoint now,
                           std::vector<NodeEvent>& out) {
  Module& m = modules_[module_index];
  if (local < m.pending.size() && m.pending[local].active) {
    const PendingRename p = m.pending[local];
    if (now < p.expires) {
      close_rename(m, local);
      if (confirm_rename(module_index, local, p, now, out)) return;
    } else {
      out.push_back(unconfirmed_event(module_index, local, p, now));
      close_rename(m, local);
    }
  }
  // CiA 301: a boot-up announces pre-operational.
  record_boot(module_index, local, NodeEvent::Kind::booted, NmtState::pre_operational,
              m.profile == IdProfile::qd ? LoaderState::in_application : LoaderState::none, now,
              out);
}

void NodeTable::on_loader_boot_up(std::size_t module_index, NodeId local, TimePoint now,
                                  std::vector<NodeEvent>& out) {
  // The loader sends no heartbeat: in_loader is not watched.
  record_boot(module_index, local, NodeEvent::Kind::loader_booted, NmtState::boot_up,
              LoaderState::in_loader, now, out);
}

void NodeTable::on_found_in_loader(std::size_t module_index, NodeId local, TimePoint now,
                                   std::vector<NodeEvent>& out) {
  if (module_index >= modules_.size()) return;
  Module& m = modules_[module_index];
  if (m.profile != IdProfile::qd || local == 0 || local >= m.slots.size()) return;
  const NodeRecord& r = m.slots[local].record;
  if (r.known && r.state != NmtState::unknown) return;
  // As a loader boot-up records it, but discovered: no boot of either kind is counted.
  record_boot(module_index, local, NodeEvent::Kind::discovered, NmtState::boot_up,
              LoaderState::in_loader, now, out);
}

void NodeTable::record_boot(std::size_t module_index, NodeId local, NodeEvent::Kind kind,
                            NmtState state, LoaderState loader, TimePoint now,
                            std::vector<NodeEvent>& out) {
  Module& m = modules_[module_index];
  Slot& s = m.slots[local];
  NodeRecord& r = s.record;
  const NmtState previous = r.known ? r.state : NmtState::boot_up;
  if (!r.known) {
    r = NodeRecord{};
    r.known = true;
  }
  if (kind == NodeEvent::Kind::loader_booted) ++r.loader_boot_count;
  if (kind == NodeEvent::Kind::booted) ++r.boot_count;
  r.lost = false;
  r.state = state;
  r.loader = loader;
  r.last_seen = now;
  // The node's 1017h is back at its own default: measure afresh.
  r.heartbeat_time = std::chrono::milliseconds{0};
  r.heartbeat_seen = false;  // watched again from its first heartbeat
  forget_gaps(s);
  update_interval(s);
  s.heartbeat_off = false;
  s.timing = false;  // the first heartbeat may follow the boot-up at once, off its period
  set_deadline(s, due(m, s));
  NodeEvent e = event(kind, module_index, local, r, now);
  e.previous_state = previous;
  out.push_back(e);
}

bool NodeTable::confirm_rename(std::size_t module_index, NodeId local, const PendingRename& p,
                               TimePoint now, std::vector<NodeEvent>& out) {
  Module& m = modules_[module_index];
  const NodeId from = p.by_serial ? find_serial(m, p.serial) : p.from;
  if (from == local) return false;  // same id: a reset communication, i.e. a plain boot-up
  NodeRecord r;
  NmtState previous = NmtState::boot_up;
  if (from != 0 && m.slots[from].record.known) {
    Slot& old = m.slots[from];
    r = old.record;
    previous = r.state;
    // Moved, not lost: the old id's record goes without an event.
    old.record = NodeRecord{};
    old.hold_until = TimePoint{};
    old.timing = false;
    old.heartbeat_off = false;
    forget_gaps(old);
    set_deadline(old, TimePoint::max());
  }
  r.known = true;
  ++r.boot_count;
  r.lost = false;
  r.state = NmtState::pre_operational;
  r.loader = m.profile == IdProfile::qd ? LoaderState::in_application : LoaderState::none;
  r.last_seen = now;
  r.heartbeat_time = std::chrono::milliseconds{0};  // a reset communication restores 1017h
  if (p.by_serial) r.serial = p.serial;             // find_serial found no other holder
  Slot& s = m.slots[local];
  s.record = r;
  s.hold_until = TimePoint{};
  s.timing = false;
  s.heartbeat_off = false;
  forget_gaps(s);
  update_interval(s);
  set_deadline(s, due(m, s));
  NodeEvent e = event(NodeEvent::Kind::renamed, module_index, local, r, now);
  e.previous_local = from;
  e.previous_state = previous;
  out.push_back(e);
  return true;
}

void NodeTable::on_nmt_to_bus(std::size_t module_index, const can::Frame& frame, TimePoint now,
                              std::vector<NodeEvent>& out) {
  if (frame.id != canopen::cob::nmt || !frame.is_standard_data() ||
      module_index >= modules_.size()) {
    return;
  }
  Module& m = modules_[module_index];
  namespace nid = canopen::nmt_node_id;
  if (const auto change = nid::decode_change(frame)) {
    const TimePoint expires = now + confirm_window_;
    open_rename(module_index, change->next, PendingRename{true, false, change->current, 0, expires},
                now, out);
    // The node goes quiet under its old id while it resets: not lost within the window.
    if (change->current <= m.max_node) hold(m, change->current, expires);
    return;
  }
  if (const auto by_serial = nid::decode_by_serial(frame)) {
    const TimePoint expires = now + confirm_window_;
    open_rename(module_index, by_serial->next,
                PendingRename{true, true, 0, by_serial->serial, expires}, now, out);
    if (const NodeId holder = find_serial(m, by_serial->serial)) hold(m, holder, expires);
    return;
  }
  // CiA 301 node control: 2 bytes, command and node (0: all).
  if (frame.len != 2) return;
  const std::uint8_t command = frame.data[0];
  const NodeId target = frame.data[1];
  if (command != canopen::nmt::reset_node && command != canopen::nmt::reset_communication) return;
  // A boot-up is expected: the node has default_lost_after to send it.
  const TimePoint until = now + default_lost_after_;
  if (target == 0) {
    for (NodeId local = 1; local <= m.max_node; ++local) hold(m, local, until);
  } else if (target <= m.max_node) {
    hold(m, target, until);
  }
}

void NodeTable::open_rename(std::size_t module_index, NodeId next, const PendingRename& p,
                            TimePoint now, std::vector<NodeEvent>& out) {
  PendingRename& current = modules_[module_index].pending[next];
  TimePoint previous_expiry = TimePoint::max();
  if (current.active) {
    const bool repeated =
        current.by_serial == p.by_serial && current.from == p.from && current.serial == p.serial;
    // A repeated command (a master retrying) only extends the window; a different one replaces
    // the pending command, which can no longer be told apart from it.
    if (!repeated || current.expires <= now) {
      out.push_back(unconfirmed_event(module_index, next, current, now));
    }
    previous_expiry = current.expires;
  }
  current = p;
  current.active = true;
  deadline_moved(previous_expiry, current.expires);
}

void NodeTable::close_rename(Module& m, NodeId next) {
  PendingRename& p = m.pending[next];
  p.active = false;
  deadline_moved(p.expires, TimePoint::max());
}

NodeEvent NodeTable::unconfirmed_event(std::size_t module_index, NodeId next,
                                       const PendingRename& p, TimePoint now) const {
  NodeEvent e;
  e.kind = NodeEvent::Kind::rename_unconfirmed;
  e.module_index = module_index;
  e.local = next;
  e.previous_local = p.by_serial ? find_serial(modules_[module_index], p.serial) : p.from;
  if (p.by_serial) e.serial = p.serial;
  e.at = now;
  return e;
}

bool NodeTable::note_serial(std::size_t module_index, NodeId local, std::uint32_t serial) {
  if (module_index >= modules_.size()) return false;
  Module& m = modules_[module_index];
  if (local == 0 || local > m.max_node || !m.slots[local].record.known) return false;
  for (NodeId other = 1; other <= m.max_node; ++other) {
    NodeRecord& r = m.slots[other].record;
    if (other != local && r.serial == serial) r.serial.reset();
  }
  m.slots[local].record.serial = serial;
  // A by-serial command already sent for this node: it goes quiet here while it resets.
  for (const PendingRename& p : m.pending) {
    if (p.active && p.by_serial && p.serial == serial) hold(m, local, p.expires);
  }
  return true;
}

bool NodeTable::note_heartbeat_time(std::size_t module_index, NodeId local,
                                    std::chrono::milliseconds producer_time) {
  if (module_index >= modules_.size()) return false;
  Module& m = modules_[module_index];
  if (local == 0 || local > m.max_node || !m.slots[local].record.known) return false;
  Slot& s = m.slots[local];
  s.record.heartbeat_time = producer_time;
  s.heartbeat_off = producer_time == std::chrono::milliseconds{0};
  if (s.heartbeat_off) {
    // The silence that follows is no period: measured afresh when the node beats again.
    forget_gaps(s);
    s.timing = false;
  }
  update_interval(s);
  set_deadline(s, due(m, s));
  return true;
}

void NodeTable::forget_gaps(Slot& s) {
  s.gaps.fill(Duration{0});
  s.next_gap = 0;
}

void NodeTable::update_interval(Slot& s) {
  NodeRecord& r = s.record;
  if (r.heartbeat_time != std::chrono::milliseconds{0}) {
    r.interval = r.heartbeat_time;
    return;
  }
  // The longest recent gap: one short gap (an extra heartbeat) cannot shrink the period, and a
  // node that slows down is followed at once.
  r.interval = *std::max_element(s.gaps.begin(), s.gaps.end());
}

void NodeTable::tick(TimePoint now, std::vector<NodeEvent>& out) {
  if (!earliest_dirty_ && earliest_ > now) return;
  TimePoint next = TimePoint::max();
  for (std::size_t mi = 0; mi < modules_.size(); ++mi) {
    Module& m = modules_[mi];
    for (NodeId id = 1; id < m.pending.size(); ++id) {
      PendingRename& p = m.pending[id];
      if (!p.active) continue;
      if (p.expires <= now) {
        out.push_back(unconfirmed_event(mi, id, p, now));
        p.active = false;
      } else {
        next = std::min(next, p.expires);
      }
    }
    for (NodeId local = 1; local <= m.max_node; ++local) {
      Slot& s = m.slots[local];
      if (s.deadline > now) {
        next = std::min(next, s.deadline);
        continue;
      }
      s.record.lost = true;
      s.deadline = TimePoint::max();
      s.timing = false;
      out.push_back(event(NodeEvent::Kind::lost, mi, local, s.record, now));
    }
  }
  earliest_ = next;
  earliest_dirty_ = false;
}

std::optional<NodeTable::TimePoint> NodeTable::next_deadline() const {
  if (earliest_dirty_) {
    earliest_ = scan_earliest();
    earliest_dirty_ = false;
  }
  if (earliest_ == TimePoint::max()) return std::nullopt;
  return earliest_;
}

NodeTable::TimePoint NodeTable::scan_earliest() const {
  TimePoint earliest = TimePoint::max();
  for (const Module& m : modules_) {
    for (const PendingRename& p : m.pending) {
      if (p.active) earliest = std::min(earliest, p.expires);
    }
    for (const Slot& s : m.slots) earliest = std::min(earliest, s.deadline);
  }
  return earliest;
}

const NodeRecord* NodeTable::node(std::size_t module_index, NodeId local) const {
  if (module_index >= modules_.size()) return nullptr;
  const Module& m = modules_[module_index];
  if (local == 0 || local > m.max_node || !m.slots[local].record.known) return nullptr;
  return &m.slots[local].record;
}

void NodeCounts::add(NmtState state, bool is_lost, bool is_in_loader) {
  if (is_lost) {
    ++lost;
  } else if (is_in_loader) {
    ++in_loader;
  } else if (state == NmtState::operational) {
    ++operational;
  } else if (state == NmtState::stopped) {
    ++stopped;
  } else if (state == NmtState::unknown) {
    ++unknown;
  } else {
    ++pre_operational;
  }
}

NodeCounts NodeTable::counts(std::size_t module_index) const {
  NodeCounts c;
  for_each_known(module_index, [&c](NodeId, const NodeRecord& r) {
    c.add(r.state, r.lost, r.loader == LoaderState::in_loader);
  });
  return c;
}

NodeCounts NodeTable::counts() const {
  NodeCounts all;
  for (std::size_t mi = 0; mi < modules_.size(); ++mi) {
    const NodeCounts c = counts(mi);
    all.operational += c.operational;
    all.pre_operational += c.pre_operational;
    all.stopped += c.stopped;
    all.in_loader += c.in_loader;
    all.lost += c.lost;
    all.unknown += c.unknown;
  }
  return all;
}

NodeTable::Duration NodeTable::lost_after(std::size_t module_index, NodeId local) const {
  if (module_index >= modules_.size()) return default_lost_after_;
  const Module& m = modules_[module_index];
  if (const NodeRecord* r = node(module_index, local)) return lost_after(m, *r);
  return m.lost_after.value_or(default_lost_after_);
}

NodeTable::Duration NodeTable::lost_after(const Module& m, const NodeRecord& r) const {
  if (m.lost_after) return *m.lost_after;
  if (r.interval == Duration{0}) return default_lost_after_;
  // No ceiling: a node beating every 5 s must not flap lost / recovered on every beat.
  return std::max<Duration>(kLostIntervals * r.interval, min_lost_after_);
}

NodeTable::TimePoint NodeTable::due(const Module& m, const Slot& s) const {
  const NodeRecord& r = s.record;
  if (!r.known || r.lost || r.loader == LoaderState::in_loader || s.heartbeat_off ||
      !r.heartbeat_seen) {
    return TimePoint::max();
  }
  return std::max(r.last_seen + lost_after(m, r), s.hold_until);
}

void NodeTable::hold(Module& m, NodeId local, TimePoint until) {
  Slot& s = m.slots[local];
  if (!s.record.known) return;
  s.hold_until = std::max(s.hold_until, until);
  set_deadline(s, due(m, s));
}

NodeId NodeTable::find_serial(const Module& m, std::uint32_t serial) const {
  for (NodeId local = 1; local <= m.max_node; ++local) {
    const NodeRecord& r = m.slots[local].record;
    if (r.known && r.serial == serial) return local;
  }
  return 0;
}

void NodeTable::set_deadline(Slot& s, TimePoint deadline) {
  const TimePoint previous = s.deadline;
  s.deadline = deadline;
  deadline_moved(previous, deadline);
}

void NodeTable::deadline_moved(TimePoint from, TimePoint to) {
  if (earliest_dirty_) return;
  if (to < earliest_) {
    earliest_ = to;
  } else if (from == earliest_ && to != from) {
    earliest_dirty_ = true;  // the earliest moved later: next_deadline() rescans once
  }
}

NodeEvent NodeTable::event(NodeEvent::Kind kind, std::size_t module_index, NodeId local,
                           const NodeRecord& r, TimePoint now) {
  NodeEvent e;
  e.kind = kind;
  e.module_index = module_index;
  e.local = local;
  e.state = r.state;
  e.previous_state = r.state;
  e.boot_count = r.boot_count;
  e.serial = r.serial;
  e.at = now;
  return e;
}

}  // namespace canbridge::bridge
