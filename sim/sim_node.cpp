#include "sim/sim_node.hpp"

#include <algorithm>
#include <stdexcept>

#include "canopen/little_endian.hpp"
#include "canopen/nmt_node_id.hpp"
#include "canopen/pdop.hpp"
#include "canopen/sdo_abort.hpp"
#include "sim/connection_set.hpp"
#include "sim/emcy_producer.hpp"
#include "sim/firmware_image.hpp"
#include "sim/lss_slave.hpp"
#include "sim/pdo_engine.hpp"
#include "sim/qd_event_flags.hpp"
#include "sim/rpdop_receiver.hpp"
#include "sim/sdo_server.hpp"

namespace canbridge::sim {

using canopen::NmtState;
using canopen::SdoAbort;

namespace {

constexpr std::size_t kMaxReceivedPackets = 16;

std::uint32_t default_device_type(NodeKind kind) {
  switch (kind) {
    case NodeKind::qd:
      // seeds/003: a manufacturer profile, so profile number 0 in the low 16 bits; the high 16
      // bits carry the profile version (1.0).
      return 0x00010000;
    case NodeKind::microcanopen:
    case NodeKind::fpga:
    case NodeKind::cia301:
      return 0x00000191;  // CiA 401 generic I/O, as seeds/002 suggests
  }
  return 0;
}

SdoLevel sdo_level(NodeKind kind) {
  switch (kind) {
    case NodeKind::microcanopen:  // seeds/002: expedited only
    case NodeKind::fpga:          // seeds/000: no CPU, expedited only
      return SdoLevel::expedited;
    case NodeKind::qd:
    case NodeKind::cia301:
      return SdoLevel::block;
  }
  return SdoLevel::expedited;
}

canopen::NodeId max_node_id(NodeKind kind) {
  // qd: restricted connection set (seeds/003); fpga: the 5-bit node field of PDOP (seeds/000).
  return kind == NodeKind::qd || kind == NodeKind::fpga ? 31 : canopen::kMaxNodeId;
}

void add_identity(ObjectDictionary& od, const NodeSpec& spec, std::uint32_t device_type) {
  od.add_unsigned(SimNode::kDeviceType, 0, Access::constant, device_type, 4);
  od.add_unsigned(SimNode::kIdentity, 0, Access::constant, 4, 1);  // highest sub-index
  od.add_unsigned(SimNode::kIdentity, 1, Access::ro, spec.identity.vendor_id, 4);
  od.add_unsigned(SimNode::kIdentity, 2, Access::ro, spec.identity.product_code, 4);
  od.add_unsigned(SimNode::kIdentity, 3, Access::ro, spec.identity.revision, 4);
  od.add_unsigned(SimNode::kIdentity, 4, Access::ro, spec.identity.serial, 4);
}

// Process values (2000h..9FFFh), which survive a reset communication.
std::vector<OdEntry> process_values(const ObjectDictionary* od) {
  std::vector<OdEntry> kept;
  if (od == nullptr) return kept;
  for (const auto& [key, entry] : od->entries()) {
    if (entry.index >= 0x2000) kept.push_back(entry);
  }
  return kept;
}

// The application's dictionary without its PDO objects: identity, error register, heartbeat,
// the kind's own objects and the rig's objects.
std::unique_ptr<ObjectDictionary> application_dictionary(const NodeSpec& spec,
                                                         std::uint32_t application_checksum) {
  auto od = std::make_unique<ObjectDictionary>();
  add_identity(*od, spec, spec.device_type);
  od->add_unsigned(SimNode::kErrorRegister, 0, Access::ro, 0, 1);
  od->add_unsigned(SimNode::kHeartbeatTime, 0, Access::rw, spec.heartbeat_ms, 2);
  if (spec.kind == NodeKind::qd) {
    // Writing 0 (stop program) hands the node back to its loader, the way a master starts a
    // firmware update; 1 is the running application.
    od->add_unsigned(SimNode::kProgramControl, 0, Access::constant, 1, 1);
    od->add_unsigned(SimNode::kProgramControl, 1, Access::rw, 1, 1);
    od->add_unsigned(SimNode::kProgramIdentification, 0, Access::constant, 1, 1);
    od->add_unsigned(SimNode::kProgramIdentification, 1, Access::ro, application_checksum, 4);
  }
  if (spec.kind == NodeKind::fpga) {
    od->add_unsigned(SimNode::kRpdopPacketCount, 0, Access::constant, 4, 1);
    for (std::uint8_t n = 1; n <= 4; ++n) {
      od->add_unsigned(SimNode::kRpdopPacketCount, n, Access::ro, 0, 4);
    }
  }
  for (const auto& object : spec.objects) {
    od->add(object.index, object.sub, object.access, object.type, object.value);
  }
  return od;
}

// qd and fpga PDOs always use their kind's COB-IDs; others only when the rig gives none. The
// defaults derive from `id`, the node's current id.
std::vector<PdoSpec> with_default_cob_ids(std::vector<PdoSpec> pdos, NodeKind kind,
                                          canopen::NodeId id, bool transmit) {
  for (auto& pdo : pdos) {
    const bool fixed = kind == NodeKind::qd || kind == NodeKind::fpga;
    if (fixed || !pdo.cob_id) {
      const auto cob = transmit ? default_tpdo_cob_id(kind, id, pdo.number)
                                : default_rpdo_cob_id(kind, id, pdo.number);
      if (!cob) throw std::invalid_argument("PDO number out of range for the node's kind");
      pdo.cob_id = *cob;
    }
  }
  return pdos;
}

}  // namespace

SimNode::SimNode(const NodeSpec& spec) : spec_(spec), id_(spec.node_id) {
  if (id_ == 0 || id_ > max_node_id(spec_.kind)) {
    throw std::invalid_argument(std::string("node id out of range for kind ") +
                                to_string(spec_.kind));
  }
  if (spec_.device_type == 0) spec_.device_type = default_device_type(spec_.kind);
  if (spec_.kind == NodeKind::qd && (spec_.device_type & 0xFFFF) != 0) {
    throw std::invalid_argument("qd device type must have profile number 0 (low 16 bits)");
  }
  application_valid_ = spec_.kind != NodeKind::qd || spec_.loader.application_valid;
  // The application the node left the factory with; a download replaces it.
  const std::uint8_t factory[] = {'q', 'd', '-', 'a', 'p', 'p', '-', id_};
  application_checksum_ = application_valid_ ? firmware::crc32(factory) : 0;
  build_application(false);
  if (spec_.kind == NodeKind::qd) build_loader();
  if (spec_.kind == NodeKind::cia301) {
    const auto& i = spec_.identity;
    lss_ = std::make_unique<LssSlave>(
        LssSlaveOptions{{i.vendor_id, i.product_code, i.revision, i.serial}, id_, true});
  }
}

SimNode::~SimNode() = default;

std::chrono::milliseconds SimNode::heartbeat_period() const {
  return std::chrono::milliseconds(od_->get_unsigned(kHeartbeatTime, 0).value_or(0));
}

void SimNode::build_application(bool keep_process_values) {
  // Process values survive a reset communication; everything else is rebuilt so that
  // id-derived COB-IDs follow the current node id.
  const std::vector<OdEntry> kept =
      keep_process_values ? process_values(od_.get()) : std::vector<OdEntry>{};
  auto od = application_dictionary(spec_, application_checksum_);
  PdoEngine::InstallOptions install;
  install.fixed_cob_ids = spec_.kind == NodeKind::qd || spec_.kind == NodeKind::fpga;
  install.fixed_mapping = install.fixed_cob_ids;
  PdoEngine::install(*od, with_default_cob_ids(spec_.tpdos, spec_.kind, id_, true),
                     with_default_cob_ids(spec_.rpdos, spec_.kind, id_, false), install);

  for (const auto& entry : kept) od->set_bytes(entry.index, entry.sub, entry.value);

  // The engines hold references into the dictionary: rebuild them with it.
  emcy_ = std::make_unique<EmcyProducer>(*od, id_, spec_.emcy);
  qd_flags_.reset();
  if (spec_.kind == NodeKind::qd) {
    qd_flags_ = std::make_unique<QdEventFlags>(*od, *emcy_, spec_.emcy.holdoff);
  }
  pdo_ = std::make_unique<PdoEngine>(*od, install);
  rpdop_.reset();
  if (spec_.kind == NodeKind::fpga) rpdop_ = std::make_unique<RpdopReceiver>(id_, spec_.pdop);
  SdoServerOptions sdo;
  sdo.node_id = id_;
  sdo.level = sdo_level(spec_.kind);
  sdo.timeout = spec_.sdo_timeout;
  sdo.max_block_size = spec_.sdo_block_size;
  sdo_ = std::make_unique<SdoServer>(*od, sdo);

  od->set_write_guard([this](const OdEntry& entry, std::span<const std::uint8_t> data) {
    return check_write(entry, data);
  });
  od->set_write_listener([this](const OdEntry& entry) {
    pending_writes_.push_back({false, entry.index, entry.sub});
  });
  od_ = std::move(od);
  emcy_->set_enabled(false);
}

void SimNode::build_loader() {
  // seeds/003: the loader "has no access to the application's Object Dictionary": it serves
  // identity, the download objects and nothing else.
  loader_od_ = std::make_unique<ObjectDictionary>();
  add_identity(*loader_od_, spec_, spec_.device_type);
  loader_od_->add_unsigned(kProgramData, 0, Access::constant, 1, 1);
  loader_od_->add(kProgramData, 1, Access::wo, DataType::domain, {0});
  loader_od_->add_unsigned(kProgramControl, 0, Access::constant, 1, 1);
  loader_od_->add_unsigned(kProgramControl, 1, Access::rw, 0, 1);
  loader_od_->add_unsigned(kProgramIdentification, 0, Access::constant, 1, 1);
  loader_od_->add_unsigned(kProgramIdentification, 1, Access::ro, application_checksum_, 4);
  loader_od_->add_unsigned(kFlashStatus, 0, Access::constant, 1, 1);
  // CiA 302 flash status: 0 = ok, 1 = no valid program (here: last image failed its checksum).
  loader_od_->add_unsigned(kFlashStatus, 1, Access::ro, application_valid_ ? 0 : 1, 4);
  loader_od_->set_write_guard(
      [this](const OdEntry& entry, std::span<const std::uint8_t> data) -> std::error_code {
        if (entry.index == kProgramControl && entry.sub == 1) {
          // CiA 302 program control: 0 stop, 1 start, 2 reset, 3 clear. Start needs a program
          // that passed its checksum.
          if (data[0] > 3) return SdoAbort::value_range;
          if (data[0] == 1 && !application_valid_) return SdoAbort::device_state;
        }
        return {};
      });
  loader_od_->set_write_listener([this](const OdEntry& entry) {
    pending_writes_.push_back({true, entry.index, entry.sub});
  });
  SdoServerOptions sdo;
  sdo.node_id = id_;
  sdo.level = SdoLevel::block;
  sdo.timeout = spec_.sdo_timeout;
  sdo.max_block_size = spec_.sdo_block_size;
  loader_sdo_ = std::make_unique<SdoServer>(*loader_od_, sdo);
}

std::error_code SimNode::check_write(const OdEntry& entry,
                                     std::span<const std::uint8_t> data) const {
  if (spec_.kind == NodeKind::qd && entry.index == kProgramControl && entry.sub == 1) {
    // The running application can only be stopped (back to the loader) or left running.
    return data[0] <= 1 ? std::error_code() : std::error_code(SdoAbort::value_range);
  }
  if (const auto e = pdo_->check_write(entry, data)) return e;
  if (const auto e = emcy_->check_write(entry, data)) return e;
  if (qd_flags_) {
    if (const auto e = qd_flags_->check_write(entry, data)) return e;
  }
  return {};
}

can::Frame SimNode::error_control_frame(NmtState state) const {
  return can::Frame::standard(canopen::cob::heartbeat + id_, {static_cast<std::uint8_t>(state)});
}

std::vector<can::Frame> SimNode::boot(TimePoint now) {
  std::vector<can::Frame> out;
  booted_ = true;
  if (spec_.kind == NodeKind::qd) {
    enter_loader(power_on_exit(), now, out);
  } else {
    start_application(now, out);
  }
  return out;
}

void SimNode::enter_loader(LoaderExit exit, TimePoint now, std::vector<can::Frame>& out) {
  in_loader_ = true;
  ++counters_.loader_entries;
  state_ = NmtState::boot_up;
  next_heartbeat_ = TimePoint::max();
  pdo_->stop();
  sdo_->reset();
  emcy_->set_enabled(false);
  for (auto& t : traffic_) t.next = TimePoint::max();
  build_loader();
  out.push_back(can::Frame::standard(kLoaderBootUpBase + id_, {0x00}));
  // Power-on path of seeds/003: the loader checks the stored application and runs it.
  if (exit == LoaderExit::start_valid_application && application_valid_) {
    start_application(now, out);
  }
}

void SimNode::start_application(TimePoint now, std::vector<can::Frame>& out) {
  initialise(false, now, out);
  arm_traffic(now);
}

void SimNode::initialise(bool keep_process_values, TimePoint now, std::vector<can::Frame>& out) {
  in_loader_ = false;
  build_application(keep_process_values);
  ++counters_.boot_ups;
  // The boot-up message is the heartbeat frame with state 0 (CiA 301 7.2.8.3.2.1).
  out.push_back(error_control_frame(NmtState::boot_up));
  state_ = NmtState::pre_operational;
  emcy_->set_enabled(true);
  schedule_heartbeat(now);
  if (spec_.auto_start) set_state(NmtState::operational, now, out);
}

void SimNode::arm_traffic(TimePoint now) {
  traffic_.clear();
  for (const auto& t : spec_.traffic) traffic_.push_back({t, now + t.period, 0});
}

void SimNode::schedule_heartbeat(TimePoint now) {
  const auto period = heartbeat_period();
  next_heartbeat_ = period.count() == 0 ? TimePoint::max() : now + period;
}

void SimNode::set_state(NmtState state, TimePoint now, std::vector<can::Frame>& out) {
  if (state == state_) return;
  const bool was_operational = state_ == NmtState::operational;
  state_ = state;
  // CiA 301: PDOs only in operational, SDO not in stopped, EMCY not in stopped.
  if (state == NmtState::operational) {
    pdo_->start(now, out);
  } else if (was_operational) {
    pdo_->stop();
    if (rpdop_) rpdop_->reset();
  }
  if (state == NmtState::stopped) sdo_->reset();
  emcy_->set_enabled(state != NmtState::stopped);
}

std::vector<can::Frame> SimNode::on_frame(const can::Frame& frame, TimePoint now) {
  std::vector<can::Frame> out;
  if (!booted_ || frame.is_extended() || frame.is_error()) return out;
  if (lss_ && frame.id == canopen::cob::lss_master) {
    lss_->on_frame(frame, out);
    return out;
  }
  if (frame.id == canopen::cob::nmt && !frame.is_remote()) {
    if (in_loader_) {
      handle_loader_nmt(frame, now, out);
    } else {
      handle_nmt(frame, now, out);
    }
    return out;
  }
  if (in_loader_) {
    if (frame.id == canopen::sdo::request_cob(id_) && !frame.is_remote()) {
      loader_sdo_->on_request(frame, now, out);
      apply_pending_writes(now, out);
    }
    return out;
  }
  // Every node sees every frame on its bus, so most frames end here untouched. Only an SDO
  // request or an RPDO can change mapped values; only then is change of state checked (the
  // timers are on_tick's business).
  bool values_changed = false;
  if (frame.id == canopen::sdo::request_cob(id_) && !frame.is_remote()) {
    if (state_ != NmtState::stopped) {
      sdo_->on_request(frame, now, out);
      values_changed = !pending_writes_.empty();
      apply_pending_writes(now, out);
    }
  } else if (frame.id == canopen::cob::sync && !frame.is_remote() && frame.len <= 1) {
    if (state_ == NmtState::operational) pdo_->on_sync(now, out);
  } else {
    values_changed = handle_pdo_traffic(frame, now, out);
  }
  if (values_changed && !in_loader_) pdo_->poll(now, out);
  return out;
}

bool SimNode::handle_pdo_traffic(const can::Frame& frame, TimePoint now,
                                 std::vector<can::Frame>& out) {
  if (state_ != NmtState::operational) return false;
  bool plain_pdo = !frame.is_remote();
  if (rpdop_) {
    std::vector<RpdopReceiver::Packet> completed;
    if (rpdop_->on_frame(frame, now, out, completed)) {
      // A one-frame packet is also the plain PDO of that COB-ID (docs/pdop.md); any packet of
      // two or more fragments is longer than 8 bytes, so the size tells them apart.
      plain_pdo =
          plain_pdo && completed.size() == 1 && completed.front().bytes.size() <= can::kMaxPayload;
      for (auto& packet : completed) {
        if (packet.rpdo >= 1 && packet.rpdo <= 4) {
          const auto n = static_cast<std::uint8_t>(packet.rpdo);
          od_->set_unsigned(kRpdopPacketCount, n,
                            od_->get_unsigned(kRpdopPacketCount, n).value_or(0) + 1);
        }
        received_packets_.push_back({packet.rpdo, std::move(packet.bytes)});
        if (received_packets_.size() > kMaxReceivedPackets) received_packets_.pop_front();
      }
    }
  }
  if (!plain_pdo) return false;
  switch (pdo_->on_frame(frame, now)) {
    case PdoEngine::RxResult::written:
      return true;
    case PdoEngine::RxResult::length_error:
      ++counters_.rpdo_length_errors;
      emcy_->raise(kEmcyPdoLength, 0x10 /* communication error */, {}, now, out);
      return false;
    case PdoEngine::RxResult::not_mine:
    case PdoEngine::RxResult::ignored:
      return false;
  }
  return false;
}

void SimNode::handle_nmt(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out) {
  if (spec_.kind == NodeKind::fpga && handle_node_id_command(frame, now, out)) return;
  // NMT node control is exactly 2 bytes: command, node id (0 = all nodes).
  if (frame.len != 2) return;
  const std::uint8_t target = frame.data[1];
  if (target != 0 && target != id_) return;
  switch (frame.data[0]) {
    case canopen::nmt::start:
      set_state(NmtState::operational, now, out);
      break;
    case canopen::nmt::stop:
      set_state(NmtState::stopped, now, out);
      break;
    case canopen::nmt::enter_pre_operational:
      set_state(NmtState::pre_operational, now, out);
      break;
    case canopen::nmt::reset_node:
      adopt_lss_node_id();
      // Application reset: every object back to its power-on value. A qd node restarts in its
      // loader, as after power-on.
      if (spec_.kind == NodeKind::qd) {
        enter_loader(power_on_exit(), now, out);
      } else {
        start_application(now, out);
      }
      break;
    case canopen::nmt::reset_communication:
      adopt_lss_node_id();
      // Only the communication profile area is reset; process values stay.
      initialise(true, now, out);
      break;
    default:
      break;  // unknown command specifiers are ignored, as CiA 301 slaves do
  }
}

void SimNode::handle_loader_nmt(const can::Frame& frame, TimePoint now,
                                std::vector<can::Frame>& out) {
  if (frame.len != 2) return;
  const std::uint8_t target = frame.data[1];
  if (target != 0 && target != id_) return;
  switch (frame.data[0]) {
    case canopen::nmt::start:
    case canopen::nmt::enter_pre_operational:
      // seeds/003: with a correct checksum "the node can be sent into its normal Preoperational
      // mode by sending the usual network command".
      if (application_valid_) {
        start_application(now, out);
        if (frame.data[0] == canopen::nmt::start) set_state(NmtState::operational, now, out);
      }
      break;
    case canopen::nmt::reset_node:
    case canopen::nmt::reset_communication:
      enter_loader(power_on_exit(), now, out);
      break;
    default:
      break;
  }
}

bool SimNode::handle_node_id_command(const can::Frame& frame, TimePoint now,
                                     std::vector<can::Frame>& out) {
  namespace cmd = canopen::nmt_node_id;
  if (frame.len == 0 || (frame.data[0] != cmd::kChange && frame.data[0] != cmd::kBySerial)) {
    return false;
  }
  if (const auto change = cmd::decode_change(frame)) {
    if (change->current == id_) rename(change->next, now, out);
  } else if (const auto by_serial = cmd::decode_by_serial(frame)) {
    if (by_serial->serial == spec_.identity.serial) rename(by_serial->next, now, out);
  }
  return true;  // malformed renames are ignored, never misread as another command
}

void SimNode::rename(canopen::NodeId next, TimePoint now, std::vector<can::Frame>& out) {
  // docs/nmt-node-id.md: store the id, reset communication with it, boot-up as confirmation.
  id_ = next;
  ++counters_.renames;
  initialise(true, now, out);
}

void SimNode::adopt_lss_node_id() {
  // CiA 305: a node-id configured over LSS takes effect at the next reset.
  if (!lss_) return;
  if (const auto next = lss_->pending_node_id()) {
    id_ = *next;
    lss_->set_active_node_id(id_);
  }
}

void SimNode::apply_pending_writes(TimePoint now, std::vector<can::Frame>& out) {
  auto writes = std::move(pending_writes_);
  pending_writes_.clear();
  for (const auto& w : writes) {
    if (w.loader) {
      if (!in_loader_) continue;
      if (w.index == kProgramData && w.sub == 1) {
        const OdEntry* image = loader_od_->find(kProgramData, 1);
        const auto verdict = firmware::verify(image->value);
        // The image overwrote the application bank: from now on only it counts.
        application_valid_ = verdict.valid;
        application_checksum_ = verdict.checksum;
        loader_od_->set_unsigned(kProgramIdentification, 1, verdict.checksum);
        loader_od_->set_unsigned(kFlashStatus, 1, verdict.valid ? 0 : 1);
        loader_od_->set_bytes(kProgramData, 1, {});  // the bank holds it now
        if (verdict.valid) {
          ++counters_.images_accepted;
        } else {
          ++counters_.images_rejected;
          // EMCY: code 6200h, error register generic, manufacturer bytes "CRC".
          out.push_back(can::Frame::standard(canopen::cob::emcy + id_,
                                             {0x00, 0x62, 0x01, 'C', 'R', 'C', 0, 0}));
        }
      } else if (w.index == kProgramControl && w.sub == 1) {
        const auto command = loader_od_->get_unsigned(kProgramControl, 1).value_or(0);
        if (command == 1) {
          start_application(now, out);
          return;  // the loader and its pending writes are gone
        }
        if (command == 2) {
          enter_loader(power_on_exit(), now, out);
          return;
        }
        if (command == 3) {
          application_valid_ = false;
          application_checksum_ = 0;
          loader_od_->set_unsigned(kProgramIdentification, 1, 0);
          loader_od_->set_unsigned(kFlashStatus, 1, 1);
        }
      }
      continue;
    }
    const OdEntry* entry = od_->find(w.index, w.sub);
    if (entry == nullptr) continue;
    if (w.index == kHeartbeatTime) {
      // CiA 301: a new producer heartbeat time applies at once.
      schedule_heartbeat(now);
    } else if (spec_.kind == NodeKind::qd && w.index == kProgramControl && w.sub == 1 &&
               od_->get_unsigned(kProgramControl, 1) == 0u) {
      // Stop program: back into the loader, which now waits for a new image or a start.
      enter_loader(LoaderExit::wait_for_command, now, out);
      return;
    }
    pdo_->on_written(*entry, now, out);
    emcy_->on_written(*entry, now, out);
    if (qd_flags_) qd_flags_->on_written(*entry, now, out);
  }
}

void SimNode::run_traffic(TimePoint now, std::vector<can::Frame>& out) {
  for (auto& t : traffic_) {
    while (t.next <= now) {
      t.next += t.spec.period;
      if (t.next <= now) t.next = now + t.spec.period;  // after a stall: once, no burst
      switch (t.spec.kind) {
        case TrafficSpec::Kind::counter: {
          // Wraps at the object's size; two's complement makes a negative step count down.
          if (const OdEntry* entry = od_->find(t.spec.index, t.spec.sub)) {
            od_->set_unsigned(
                t.spec.index, t.spec.sub,
                canopen::load_le(entry->value) + static_cast<std::uint64_t>(t.spec.step));
          }
          break;
        }
        case TrafficSpec::Kind::pdop_sample: {
          // Sample layout: a 4-byte little-endian sequence number, then bytes (seq + i) mod 256,
          // so a receiver can check every packet for loss and corruption.
          std::vector<std::uint8_t> sample(t.spec.bytes);
          for (std::size_t i = 0; i < sample.size(); ++i) {
            sample[i] = i < 4 ? static_cast<std::uint8_t>(t.sequence >> (8 * i))
                              : static_cast<std::uint8_t>(t.sequence + i);
          }
          ++t.sequence;
          auto frames = send_packet(t.spec.pdo, sample, now);
          out.insert(out.end(), frames.begin(), frames.end());
          break;
        }
        case TrafficSpec::Kind::subsystem_event: {
          auto frames = flag_subsystem(t.spec.subsystem, now);
          out.insert(out.end(), frames.begin(), frames.end());
          break;
        }
      }
    }
  }
}

std::vector<can::Frame> SimNode::flag_subsystem(unsigned subsystem, TimePoint now) {
  std::vector<can::Frame> out;
  if (qd_flags_ && !in_loader_ && booted_) qd_flags_->flag(subsystem, now, out);
  return out;
}

std::vector<can::Frame> SimNode::send_packet(unsigned tpdo, std::span<const std::uint8_t> bytes,
                                             TimePoint /*now*/) {
  std::vector<can::Frame> out;
  if (spec_.kind != NodeKind::fpga || state_ != NmtState::operational) return out;
  const auto cob = pdo_->tpdo_cob_id(tpdo);
  if (!cob) return out;
  out = canopen::pdop::fragment(static_cast<std::uint16_t>(*cob & 0x780), id_, bytes);
  if (!out.empty()) ++counters_.packets_sent;
  return out;
}

void SimNode::poll_engines(TimePoint now, std::vector<can::Frame>& out) {
  if (in_loader_) return;
  pdo_->poll(now, out);
  emcy_->poll(now, out);
  if (qd_flags_) qd_flags_->poll(now, out);
  if (rpdop_) rpdop_->poll(now);
}

std::vector<can::Frame> SimNode::on_tick(TimePoint now) {
  std::vector<can::Frame> out;
  if (!booted_) return out;
  if (in_loader_) {
    loader_sdo_->on_tick(now, out);
    return out;
  }
  if (now >= next_heartbeat_) {
    out.push_back(error_control_frame(state_));
    const auto period = heartbeat_period();
    // Keep the cadence of the schedule rather than of our wake-ups; after a long stall send one
    // heartbeat, not a burst of the missed ones.
    next_heartbeat_ += period;
    if (period.count() == 0) {
      next_heartbeat_ = TimePoint::max();
    } else if (next_heartbeat_ <= now) {
      next_heartbeat_ = now + period;
    }
  }
  sdo_->on_tick(now, out);
  run_traffic(now, out);
  poll_engines(now, out);
  return out;
}

SimNode::TimePoint SimNode::next_deadline() const {
  if (!booted_) return TimePoint::max();
  if (in_loader_) return loader_sdo_->next_deadline();
  TimePoint t = std::min(
      {next_heartbeat_, sdo_->next_deadline(), pdo_->next_deadline(), emcy_->next_deadline()});
  if (qd_flags_) t = std::min(t, qd_flags_->next_deadline());
  if (rpdop_) t = std::min(t, rpdop_->next_deadline());
  for (const auto& traffic : traffic_) t = std::min(t, traffic.next);
  return t;
}

}  // namespace canbridge::sim
