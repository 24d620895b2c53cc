#include "bridge/gateway_remote.hpp"

#include <algorithm>
#include <stdexcept>

#include "backbone/peer_stream.hpp"
#include "canopen/nmt_node_id.hpp"
#include "canopen/sdo_abort.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::bridge {

namespace {

// The object each census question uploads: a loader's flash status (1F57h:01), which only a
// loader has, or the device type (1000h:00), which every CiA 301 node has.
canopen::sdo::Multiplexer census_object(GatewayRemote::CensusQuestion question) {
  if (question == GatewayRemote::CensusQuestion::in_loader) {
    return {canopen::firmware_objects::flash_status, 1};
  }
  return {0x1000, 0};
}

// What a node is, from its device type (1000h:00) as CiA 301 splits it: the device profile
// number in the low word ("CiA401"), or profile 0 (a manufacturer's profile, seed 003's qd
// nodes) with its version in the high word ("mfr-v3"). No spaces: one field of `nodes`.
std::string device_kind(std::uint32_t device_type) {
  const std::uint32_t profile = device_type & 0xFFFFu;
  if (profile != 0) return "CiA" + std::to_string(profile);
  return "mfr-v" + std::to_string(device_type >> 16);
}

using canopen::NodeId;
using canopen::SdoAbort;

constexpr auto kLocalControl = static_cast<std::uint32_t>(SdoAbort::local_control);
constexpr auto kCannotTransfer = static_cast<std::uint32_t>(SdoAbort::cannot_transfer);
constexpr auto kBadCommand = static_cast<std::uint32_t>(SdoAbort::invalid_command);
constexpr auto kTimeout = static_cast<std::uint32_t>(SdoAbort::timeout);

// CiA 301 NMT command specifiers a remote request may send (set-node-id has its own path).
bool standard_nmt(std::uint32_t command) {
  return command == 0x01 || command == 0x02 || command == 0x80 || command == 0x81 ||
         command == 0x82;
}

std::int64_t age_ms(NodeTable::TimePoint now, NodeTable::TimePoint then) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(now - then).count();
}

}  // namespace

GatewayRemote::GatewayRemote(const NodeMap& map, const NodeTable& table,
                             std::vector<Module> modules, GatewayRemoteOptions options,
                             MasterBusy master_busy)
    : map_(&map),
      table_(&table),
      modules_(std::move(modules)),
      options_(options),
      master_busy_(std::move(master_busy)) {}

std::chrono::milliseconds GatewayRemote::timeout_of(const v1::RemoteRequest& request) const {
  return request.timeout_ms() != 0 ? std::chrono::milliseconds(request.timeout_ms())
                                   : options_.sdo_timeout;
}

void GatewayRemote::on_request(const v1::RemoteRequest& request, TimePoint now) {
  const std::uint64_t id = request.request_id();
  if ((id & kProbeIdBit) != 0) {
    // The gateway's own ids (ask_silent_nodes): taken from a peer, the request could be mistaken
    // for a probe and its answer kept here. It is refused, answered, and never remembered, so a
    // probe of the same id is not taken for its duplicate.
    ++counters_.requests;
    ++counters_.failed;
    push_result(id, kBadCommand, "request ids from 2^63 up are reserved for the gateway");
    return;
  }
  if (known_id(id)) {
    ++counters_.duplicates;
    return;
  }
  ++counters_.requests;
  take(request, now);
}

void GatewayRemote::take(const v1::RemoteRequest& request, TimePoint now) {
  const std::uint64_t id = request.request_id();
  if (request.op_case() == v1::RemoteRequest::kNodes) {
    answer_nodes(request, now);
    return;
  }
  const std::optional<std::size_t> m = map_->index_of(request.module_id());
  if (!m || *m >= modules_.size()) {
    return answer(id, kBadCommand,
                  "module " + std::to_string(request.module_id()) + " is not served here");
  }
  const NodeId max_node = max_node_id(map_->modules()[*m].profile);
  std::uint32_t node = request.local_node();
  // Addressed by its surface id (the default network): the local id behind it in the live map
  // now; the surface's claims name the module, not the local id.
  if (request.surface_node() != 0) {
    const auto owner = request.surface_node() <= canopen::kMaxNodeId
                           ? map_->owner_of_surface(static_cast<NodeId>(request.surface_node()))
                           : std::nullopt;
    if (!owner || owner->module_index != *m) {
      return answer(id, kBadCommand,
                    "surface node " + std::to_string(request.surface_node()) +
                        " is not a node of module " + std::to_string(request.module_id()));
    }
    node = owner->local;
  }
  switch (request.op_case()) {
    case v1::RemoteRequest::kLss:
      if (!modules_[*m].lss) {
        answer(id, kCannotTransfer,
               "LSS is not allowed on module " + std::to_string(request.module_id()));
        results_.back().set_not_supported(true);
        return;
      }
      {
        bool inquiry = false;
        std::string why;
        if (!lss_service(request.lss(), timeout_of(request), inquiry, why)) {
          return answer(id, kBadCommand, why);
        }
      }
      break;  // one LSS service at a time on the module: its lane is node 0
    case v1::RemoteRequest::kFlash:
      if (node == 0 || node > max_node || request.flash().block_size() > 127) {
        return answer(id, kBadCommand, "invalid flash request");
      }
      break;
    case v1::RemoteRequest::kNmt: {
      const std::uint32_t command = request.nmt().command();
      if (command == canopen::nmt_node_id::kChange) {
        if (!canopen::nmt_node_id::valid_node_id(static_cast<NodeId>(std::min(node, 255u))) ||
            !canopen::nmt_node_id::valid_node_id(
                static_cast<NodeId>(std::min(request.nmt().new_node(), 255u)))) {
          return answer(id, kBadCommand, "set-node-id takes node ids 1..31");
        }
        break;  // queued behind the node's other requests
      }
      if (!standard_nmt(command) || node > max_node) {
        return answer(id, kBadCommand, "not an NMT command this gateway sends");
      }
      if (node == 0) {  // every node of the module: no one node's queue to wait in
        write_nmt(*m, static_cast<std::uint8_t>(command), 0);
        return answer(id, 0, {});
      }
      break;
    }
    case v1::RemoteRequest::kSdo: {
      const v1::SdoOp& sdo = request.sdo();
      if (node == 0 || node > max_node || sdo.index() > 0xFFFF || sdo.subindex() > 0xFF ||
          sdo.block_size() > 127) {
        return answer(id, kBadCommand, "invalid SDO request");
      }
      break;
    }
    case v1::RemoteRequest::kNodes:
    case v1::RemoteRequest::OP_NOT_SET:
      return answer(id, kBadCommand, "no operation in the request");
  }
  const auto lane_node = static_cast<NodeId>(request.has_lss() ? 0 : node);
  Lane& lane = lanes_[{*m, lane_node}];
  if (lane.queue.size() >= options_.max_queued_per_node) {
    return answer(id, kLocalControl, "too many requests queued for the node");
  }
  lane.queue.push_back({request, std::nullopt});
  pump(now);
}

void GatewayRemote::on_cancel(const v1::RemoteCancel& cancel, TimePoint now) {
  const std::uint64_t id = cancel.request_id();
  for (auto& [key, lane] : lanes_) {
    auto queued = std::find_if(lane.queue.begin(), lane.queue.end(),
                               [id](const Job& job) { return job.request.request_id() == id; });
    auto when = v1::RemoteResult::BEFORE_START;
    if (queued != lane.queue.end()) {
      lane.queue.erase(queued);  // never executed
    } else if (lane.running && lane.running->id == id) {
      when = v1::RemoteResult::WHILE_RUNNING;  // what it wrote before the abort stays written
      const auto cancelled = canopen::make_error_code(SdoAbort::local_control);
      if (lane.running->sdo) lane.running->sdo->abort(cancelled, frames_for(key.first));
      if (lane.running->flash) {
        lane.running->flash->abort(cancelled, frames_for(key.first));
        --flashes_running_;
      }
      lane.running.reset();
    } else {
      continue;
    }
    ++counters_.cancelled;
    answer(id, kLocalControl, "cancelled");
    results_.back().set_cancelled(when);
    pump(now);
    return;
  }
  // Already answered (the result crossed the cancel) or never seen: nothing to do.
}

bool GatewayRemote::on_bus_frame(std::size_t module_index, const can::Frame& frame, TimePoint now) {
  if ((lanes_.empty() && yielded_.empty()) || !frame.is_standard_data()) return false;
  if (frame.id == canopen::cob::lss_slave) {
    // An answer to the gateway's LSS service: the runner's (a surface master did not ask).
    auto it = lanes_.find({module_index, 0});
    if (it == lanes_.end() || !it->second.running || !it->second.running->lss) return false;
    Lane& lane = it->second;
    lane.running->lss->on_frame(frame, now);
    if (lane.running->lss->finished()) {
      finish_lss(lane);
      pump(now);
    }
    return true;
  }
  const bool sdo_response =
      frame.id > canopen::cob::sdo_tx && frame.id <= canopen::cob::sdo_tx + canopen::kMaxNodeId;
  if (flashes_running_ != 0 && !sdo_response) {
    // Boot-ups (application 0x700+N, loader 0x720+N) end a flash's waits; the surface sees them
    // too. Each flash picks its node's frames.
    bool ended = false;
    for (auto& [key, lane] : lanes_) {
      if (key.first != module_index || !lane.running || !lane.running->flash) continue;
      lane.running->flash->on_frame(frame, now, frames_for(module_index));
      after_flash(lane, now);
      ended = ended || !lane.running;
    }
    if (ended) pump(now);
    return false;
  }
  if (!sdo_response) return false;
  const auto node = static_cast<NodeId>(frame.id - canopen::cob::sdo_tx);
  if (!yielded_.empty() && take_late_census_answer(module_index, node, frame, now)) return true;
  auto it = lanes_.find({module_index, node});
  if (it == lanes_.end() || !it->second.running || !it->second.running->uses_channel()) {
    return false;
  }
  Lane& lane = it->second;
  ++counters_.sdo_frames_taken;
  if (lane.running->flash) {
    lane.running->flash->on_frame(frame, now, frames_for(module_index));
    after_flash(lane, now);
  } else {
    lane.running->sdo->on_frame(frame, now, frames_for(module_index));
    if (lane.running->sdo->finished()) {
      finish_sdo(lane);
    } else {
      report_sdo_progress(*lane.running, now);
    }
  }
  if (!lane.running) pump(now);
  return true;
}

void GatewayRemote::on_node_event(const NodeEvent& event, TimePoint now) {
  const bool boot = event.kind == NodeEvent::Kind::booted || event.kind == NodeEvent::Kind::renamed;
  const bool unconfirmed = event.kind == NodeEvent::Kind::rename_unconfirmed;
  if (!boot && !unconfirmed) return;
  bool ended = false;
  for (auto& [key, lane] : lanes_) {
    if (key.first != event.module_index || !lane.running || lane.running->new_node == 0 ||
        lane.running->new_node != event.local) {
      continue;
    }
    if (boot) {
      // The id the surface addresses the node by now, in the live map that followed the rename
      // (1 byte, 0: none): a client told "node 5 is now node 6" went on using 6 while the map had
      // kept the node at its surface id 5.
      const NodeId surface = map_->surface_of(event.module_index, event.local);
      answer(lane.running->id, 0, {}, std::string(1, static_cast<char>(surface)));
    } else {
      answer(lane.running->id, kTimeout, "no boot-up on new id");
    }
    lane.running.reset();
    ended = true;
  }
  if (ended) pump(now);
}

void GatewayRemote::tick(TimePoint now) {
  for (auto& [key, lane] : lanes_) {
    if (!lane.running) continue;
    Running& r = *lane.running;
    if (r.sdo && now >= r.sdo->deadline()) {
      r.sdo->on_timeout(now, frames_for(key.first));
      if (r.sdo->finished()) finish_sdo(lane);
    } else if (r.lss && now >= r.lss->deadline()) {
      r.lss->on_timeout(now);
      if (r.lss->finished()) finish_lss(lane);
    } else if (r.flash && now >= r.flash->deadline()) {
      r.flash->on_timeout(now, frames_for(key.first));
      after_flash(lane, now);
    } else if (r.new_node != 0 && now >= r.deadline) {
      answer(r.id, kTimeout, "no boot-up on new id");
      lane.running.reset();
    }
  }
  pump(now);
}

std::optional<GatewayRemote::TimePoint> GatewayRemote::next_deadline() const {
  TimePoint earliest = TimePoint::max();
  for (const auto& [key, lane] : lanes_) {
    if (lane.running) {
      earliest = std::min(earliest, lane.running->next_deadline());
    } else if (!lane.queue.empty() && lane.queue.front().blocked_since) {
      earliest = std::min(
          earliest, *lane.queue.front().blocked_since + timeout_of(lane.queue.front().request));
    }
  }
  if (earliest == TimePoint::max()) return std::nullopt;
  return earliest;
}

bool GatewayRemote::transferring(std::size_t module_index, NodeId local) const {
  if (lanes_.empty()) return false;
  auto it = lanes_.find({module_index, local});
  return it != lanes_.end() && it->second.running && it->second.running->uses_channel();
}

bool GatewayRemote::take_late_census_answer(std::size_t module_index, NodeId node,
                                            const can::Frame& frame, TimePoint now) {
  const auto y = yielded_.find({module_index, node});
  if (y == yielded_.end()) return false;
  const YieldedQuestion q = y->second;
  if (now >= q.until) {
    yielded_.erase(y);  // too late to be the census's answer
    return false;
  }
  // An initiate answer or an abort names its object in bytes 1-3.
  if (frame.len != 8 || canopen::sdo::read_multiplexer(frame) != q.object) return false;
  yielded_.erase(y);
  ++counters_.census_late_answers;
  return true;
}

bool GatewayRemote::yield_census(std::size_t module_index, NodeId local) {
  auto it = lanes_.find({module_index, local});
  if (it == lanes_.end() || !it->second.running) return false;
  const auto probe = probes_.find(it->second.running->id);
  if (probe == probes_.end()) return false;
  // Not pumped here: the lane's next job waits for the master's transfer, which starts now.
  yielded_[{module_index, local}] = {census_object(probe->second.question),
                                     it->second.running->next_deadline()};
  it->second.running.reset();
  probes_.erase(probe);
  ++counters_.census_yielded;
  return true;
}

GatewayRemote::MasterCollision GatewayRemote::on_master_frame(std::size_t module_index,
                                                              const can::Frame& local) {
  if (local.is_extended() || local.id <= canopen::cob::sdo_rx ||
      local.id > canopen::cob::sdo_rx + canopen::kMaxNodeId || local.len < 4) {
    return {};
  }
  const auto node = static_cast<NodeId>(local.id - canopen::cob::sdo_rx);
  if (!transferring(module_index, node)) return {};
  if (yield_census(module_index, node)) return {};  // the census only asks: it gives way
  if ((local.data[0] >> 5) == canopen::sdo::ccs::abort) return {true, std::nullopt};  // its own
  return {true, canopen::sdo::abort_response(node, canopen::sdo::read_multiplexer(local),
                                             canopen::SdoAbort::local_control)};
}

std::vector<v1::RemoteProgress> GatewayRemote::take_progress() {
  std::vector<v1::RemoteProgress> out;
  for (auto& [id, progress] : progress_) out.push_back(std::move(progress));
  progress_.clear();
  return out;
}

std::size_t GatewayRemote::pending() const {
  std::size_t n = 0;
  for (const auto& [key, lane] : lanes_) n += lane.queue.size() + (lane.running ? 1 : 0);
  return n;
}

void GatewayRemote::ask_silent_nodes(std::size_t module_index,
                                     const std::vector<canopen::NodeId>& locals,
                                     CensusQuestion question, std::chrono::milliseconds timeout,
                                     TimePoint now) {
  if (module_index >= modules_.size()) return;
  for (const canopen::NodeId local : locals) {
    v1::RemoteRequest r;
    r.set_request_id(kProbeIdBit | ++probes_sent_);
    r.set_module_id(modules_[module_index].id);
    r.set_local_node(local);
    r.set_timeout_ms(static_cast<std::uint32_t>(timeout.count()));
    r.mutable_sdo()->set_upload(true);
    const canopen::sdo::Multiplexer asked = census_object(question);
    r.mutable_sdo()->set_index(asked.index);
    r.mutable_sdo()->set_subindex(asked.sub);
    probes_[r.request_id()] = {{module_index, local}, question};
    ++counters_.census_questions;
    take(r, now);
  }
}

void GatewayRemote::produce(backbone::PayloadSink& sink) {
  v1::Payload payload;
  while (has_results()) {
    *payload.mutable_remote_result() = front_result();
    const std::size_t size = payload.ByteSizeLong();
    if (sink.room() < size + 16 || !sink.reliable_room(size)) return;
    sink.send_reliable(payload.SerializeAsString());
    pop_result();
  }
  for (const v1::RemoteProgress& progress : take_progress()) {
    *payload.mutable_remote_progress() = progress;
    const std::string bytes = payload.SerializeAsString();
    if (sink.room() < bytes.size() + 16) return;
    sink.send_unreliable({reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size()});
  }
}

std::vector<GatewayRemote::CensusAsked> GatewayRemote::census(std::chrono::milliseconds timeout,
                                                              TimePoint now) {
  std::vector<CensusAsked> asked;
  for (std::size_t m = 0; m < modules_.size() && m < map_->modules().size(); ++m) {
    if (!modules_[m].census) continue;
    const IdProfile profile = map_->modules()[m].profile;
    std::vector<canopen::NodeId> silent;
    for (canopen::NodeId local = 1; local <= max_node_id(profile); ++local) {
      if (map_->surface_of(m, local) != 0 && table_->node(m, local) == nullptr) {
        silent.push_back(local);
      }
    }
    if (silent.empty()) continue;
    // qd: whether it waits in its loader (an application's refusal lists it as well).
    const CensusQuestion question =
        profile == IdProfile::qd ? CensusQuestion::in_loader : CensusQuestion::present;
    ask_silent_nodes(m, silent, question, timeout, now);
    asked.push_back({m, silent.size(), question});
  }
  return asked;
}

void GatewayRemote::answer(std::uint64_t id, std::uint32_t abort_code, std::string detail,
                           std::string data) {
  if (const auto probe = probes_.find(id); probe != probes_.end()) {
    // ask_silent_nodes(): the gateway's own question, answered to nobody but itself.
    if (abort_code == 0 && probe->second.question == CensusQuestion::in_loader) {
      found_in_loader_.push_back(probe->second.node);
    }
    probes_.erase(probe);
    remember(id);
    return;
  }
  if (abort_code != 0) ++counters_.failed;
  push_result(id, abort_code, std::move(detail), std::move(data));
  progress_.erase(id);
  remember(id);
}

void GatewayRemote::push_result(std::uint64_t id, std::uint32_t abort_code, std::string detail,
                                std::string data) {
  v1::RemoteResult& r = results_.emplace_back();
  r.set_request_id(id);
  r.set_abort_code(abort_code);
  r.set_detail(std::move(detail));
  r.set_data(std::move(data));
}

void GatewayRemote::answer_nodes(const v1::RemoteRequest& request, TimePoint now) {
  std::vector<std::size_t> modules;
  if (request.module_id() == 0) {
    for (std::size_t m = 0; m < modules_.size(); ++m) modules.push_back(m);
  } else if (const auto m = map_->index_of(request.module_id()); m && *m < modules_.size()) {
    modules.push_back(*m);
  } else {
    return answer(request.request_id(), kBadCommand,
                  "module " + std::to_string(request.module_id()) + " is not served here");
  }
  v1::RemoteResult& r = results_.emplace_back();
  r.set_request_id(request.request_id());
  for (const std::size_t m : modules) {
    const char* profile = to_string(map_->modules()[m].profile);
    table_->for_each_known(m, [&](NodeId local, const NodeRecord& record) {
      v1::NodeRow& row = *r.add_nodes();
      row.set_module_id(modules_[m].id);
      row.set_local_node(local);
      row.set_surface_node(map_->surface_of(m, local));
      row.set_profile(profile);
      if (record.device_type) row.set_kind(device_kind(*record.device_type));
      row.set_nmt_state(static_cast<std::uint32_t>(record.state));
      row.set_in_loader(record.loader == LoaderState::in_loader);
      row.set_lost(record.lost);
      // No heartbeat since its boot-up (1017h = 0): alive, not watched, no age to show.
      row.set_heartbeat_age_ms(!record.heartbeat_seen || record.last_seen == NodeTable::TimePoint{}
                                   ? -1
                                   : age_ms(now, record.last_seen));
      row.set_last_emcy_code(record.last_emcy_code);
      row.set_last_emcy_register(record.last_emcy_register);
      row.set_last_emcy_age_ms(record.last_emcy_at ? age_ms(now, *record.last_emcy_at) : -1);
      row.set_boot_count(record.boot_count);
    });
  }
  remember(request.request_id());
}

void GatewayRemote::write_nmt(std::size_t module_index, std::uint8_t command, NodeId node) {
  frames_for(module_index).push_back(can::Frame::standard(canopen::cob::nmt, {command, node}));
}

std::vector<can::Frame>& GatewayRemote::frames_for(std::size_t module_index) {
  for (BusFrames& b : bus_frames_) {
    if (b.module_index == module_index) return b.frames;
  }
  return bus_frames_.emplace_back(BusFrames{module_index, {}}).frames;
}

void GatewayRemote::pump(TimePoint now) {
  for (auto it = lanes_.begin(); it != lanes_.end();) {
    Lane& lane = it->second;
    while (!lane.running && !lane.queue.empty()) {
      if (!start(it->first, lane, lane.queue.front(), now)) break;  // waits for the master
      lane.queue.pop_front();
    }
    if (!lane.running && lane.queue.empty()) {
      it = lanes_.erase(it);
    } else {
      ++it;
    }
  }
}

bool GatewayRemote::start(const LaneKey& key, Lane& lane, Job& job, TimePoint now) {
  const auto [m, node] = key;
  const v1::RemoteRequest& request = job.request;
  const std::uint64_t id = request.request_id();
  if (request.has_lss()) {
    bool inquiry = false;
    std::string why;
    lane.running = Running{};
    lane.running->id = id;
    lane.running->lss = lss_service(request.lss(), timeout_of(request), inquiry, why);
    lane.running->lss_inquiry = inquiry;
    lane.running->lss->start(now, frames_for(m));
    if (lane.running->lss->finished()) finish_lss(lane);
    return true;
  }
  if (request.has_nmt()) {
    const v1::NmtOp& nmt = request.nmt();
    if (nmt.command() != canopen::nmt_node_id::kChange) {
      write_nmt(m, static_cast<std::uint8_t>(nmt.command()), node);
      answer(id, 0, {});  // NMT has no confirmation: done once written
      return true;
    }
    // The fpga's command on the module bus, as a master there would send it: the node table
    // opens the pending rename when it is written, the rename follower moves the node in the
    // live map on the boot-up, and that boot-up answers the request (on_node_event).
    const auto next = static_cast<NodeId>(nmt.new_node());
    frames_for(m).push_back(
        canopen::nmt_node_id::encode(canopen::nmt_node_id::ChangeNodeId{node, next}));
    lane.running = Running{};
    lane.running->id = id;
    lane.running->new_node = next;
    lane.running->deadline = now + options_.boot_timeout;
    return true;
  }
  // SDO and flash: first come owns the node's channel. A master's transfer through the tunnel is
  // open: wait for its end, at most this request's own timeout.
  if (master_busy_ && master_busy_(m, node)) {
    if (!job.blocked_since) {
      job.blocked_since = now;
      ++counters_.waited_for_master;
    }
    if (now < *job.blocked_since + timeout_of(request)) return false;
    answer(id, kLocalControl, "local control: a master's SDO transfer with the node stayed open");
    return true;
  }
  if (request.has_flash()) {
    canopen::FirmwareDownloadOptions options;
    options.answer_timeout = options_.flash_answer_timeout;
    options.boot_timeout = options_.boot_timeout;
    options.block_size = request.flash().block_size() != 0
                             ? static_cast<std::uint8_t>(request.flash().block_size())
                             : options_.flash_block_size;
    // The node table knows where a qd node runs; elsewhere the sequencer probes.
    canopen::FirmwareStartMode mode = canopen::FirmwareStartMode::unknown;
    if (const NodeRecord* record = table_->node(m, node)) {
      if (record->loader == LoaderState::in_loader) mode = canopen::FirmwareStartMode::loader;
      if (record->loader == LoaderState::in_application) {
        mode = canopen::FirmwareStartMode::application;
      }
    }
    const std::string& image = request.flash().image();
    try {
      lane.running = Running{};
      lane.running->id = id;
      lane.running->flash.emplace(node, std::vector<std::uint8_t>(image.begin(), image.end()),
                                  options, mode);
    } catch (const std::invalid_argument& e) {
      lane.running.reset();
      answer(id, kBadCommand, e.what());
      return true;
    }
    ++flashes_running_;
    lane.running->reported_at = now;
    lane.running->flash->start(now, frames_for(m));
    lane.running->reported = lane.running->flash->progress();
    v1::RemoteProgress& p = progress_[id];
    p.set_request_id(id);
    p.set_step(canopen::to_string(lane.running->reported.step));
    p.set_bytes_total(lane.running->reported.bytes_total);
    after_flash(lane, now);
    return true;
  }
  const v1::SdoOp& op = request.sdo();
  canopen::SdoTransferOptions options;
  options.timeout = timeout_of(request);
  options.block_size = static_cast<std::uint8_t>(op.block_size());
  const canopen::sdo::Multiplexer mux{static_cast<std::uint16_t>(op.index()),
                                      static_cast<std::uint8_t>(op.subindex())};
  try {
    lane.running = Running{};
    lane.running->id = id;
    lane.running->sdo.emplace(
        op.upload() ? canopen::SdoTransfer::upload(node, mux, options)
                    : canopen::SdoTransfer::download(
                          node, mux, std::vector<std::uint8_t>(op.data().begin(), op.data().end()),
                          options));
  } catch (const std::invalid_argument& e) {  // checked on arrival; the transfer's own rules
    lane.running.reset();
    answer(id, kBadCommand, e.what());
    return true;
  }
  lane.running->reported_at = now;
  lane.running->sdo->start(now, frames_for(m));
  if (lane.running->sdo->finished()) finish_sdo(lane);
  return true;
}

void GatewayRemote::report_sdo_progress(Running& r, TimePoint now) {
  // A long transfer (64 KiB segmented is thousands of round trips) tells the surface it is alive,
  // so the surface's answer deadline follows the transfer instead of its size being guessed.
  const std::size_t done = r.sdo->bytes_done();
  if (done == r.reported.bytes_done || now - r.reported_at < kProgressEvery) return;
  r.reported.bytes_done = done;
  r.reported_at = now;
  v1::RemoteProgress& p = progress_[r.id];
  p.set_request_id(r.id);
  p.set_step(r.sdo->is_upload() ? "upload" : "download");
  p.set_bytes_done(done);
  p.set_bytes_total(r.sdo->bytes_total());
}

void GatewayRemote::finish_sdo(Lane& lane) {
  const canopen::SdoResult& result = lane.running->sdo->result();
  if (result.ok()) {
    answer(lane.running->id, 0, {}, std::string(result.data.begin(), result.data.end()));
  } else {
    // The code says it all: the endpoint prints its text (a detail repeating it was printed
    // twice).
    answer(lane.running->id, canopen::to_abort_code(result.error), {});
  }
  lane.running.reset();
}

void GatewayRemote::after_flash(Lane& lane, TimePoint now) {
  Running& r = *lane.running;
  const canopen::FirmwareDownload& flash = *r.flash;
  if (flash.finished()) {
    const canopen::FirmwareResult& result = flash.result();
    --flashes_running_;
    if (result.ok()) {
      answer(r.id, 0, {});
    } else {
      answer(r.id, canopen::to_abort_code(result.error),
             std::string(canopen::to_string(result.step)) +
                 (result.detail.empty() ? std::string() : ": " + result.detail));
    }
    lane.running.reset();
    return;
  }
  const canopen::FirmwareProgress now_at = flash.progress();
  const bool step_changed = now_at.step != r.reported.step;
  if (!step_changed &&
      (now_at.bytes_done == r.reported.bytes_done || now - r.reported_at < kProgressEvery)) {
    return;
  }
  r.reported = now_at;
  r.reported_at = now;
  v1::RemoteProgress& p = progress_[r.id];
  p.set_request_id(r.id);
  p.set_step(canopen::to_string(now_at.step));
  p.set_bytes_done(now_at.bytes_done);
  p.set_bytes_total(now_at.bytes_total);
}

void GatewayRemote::finish_lss(Lane& lane) {
  const canopen::LssResult& result = lane.running->lss->result();
  if (result.ok()) {
    std::string value;
    if (lane.running->lss_inquiry) {
      for (int b = 0; b < 4; ++b) value.push_back(static_cast<char>(result.value >> (8 * b)));
    }
    answer(lane.running->id, 0, {}, std::move(value));
  } else if (result.error == canopen::make_error_code(canopen::LssError::timeout)) {
    answer(lane.running->id, kTimeout, "LSS: no answer");
  } else {
    answer(lane.running->id, kCannotTransfer,
           "LSS: " + result.error.message() + " (code " + std::to_string(result.answer_code) +
               ", specific " + std::to_string(result.specific_code) + ")");
  }
  lane.running.reset();
}

std::optional<canopen::LssMaster> GatewayRemote::lss_service(const v1::LssOp& op,
                                                             std::chrono::milliseconds timeout,
                                                             bool& inquiry,
                                                             std::string& why) const {
  using canopen::LssMaster;
  const std::string& c = op.command();
  const auto& args = op.args();
  inquiry = false;
  if (c == "lss_switch_glob" && args.size() == 1 && args[0] <= 1) {
    return LssMaster::switch_global(args[0] == 1, timeout);
  }
  if (c == "lss_switch_sel" && args.size() == 4) {
    return LssMaster::switch_selective({args[0], args[1], args[2], args[3]}, timeout);
  }
  if (c == "lss_set_node" && args.size() == 1 &&
      ((args[0] >= 1 && args[0] <= canopen::kMaxNodeId) || args[0] == 0xFF)) {
    return LssMaster::configure_node_id(static_cast<std::uint8_t>(args[0]), timeout);
  }
  if (c == "lss_store" && args.empty()) return LssMaster::store_configuration(timeout);
  if (c == "lss_inquire_addr" && args.size() <= 1 && (args.empty() || args[0] <= 3)) {
    inquiry = true;
    return LssMaster::inquire(static_cast<canopen::LssInquiry>(args.empty() ? 3 : args[0]),
                              timeout);
  }
  if (c == "lss_get_node" && args.empty()) {
    inquiry = true;
    return LssMaster::inquire(canopen::LssInquiry::node_id, timeout);
  }
  why = "not an LSS command with valid arguments: " + c;
  return std::nullopt;
}

void GatewayRemote::remember(std::uint64_t id) {
  if (!finished_.insert(id).second) return;
  finished_order_.push_back(id);
  if (finished_order_.size() > kRememberedIds) {
    finished_.erase(finished_order_.front());
    finished_order_.pop_front();
  }
}

bool GatewayRemote::known_id(std::uint64_t id) const {
  if (finished_.contains(id)) return true;
  for (const auto& [key, lane] : lanes_) {
    if (lane.running && lane.running->id == id) return true;
    for (const Job& job : lane.queue) {
      if (job.request.request_id() == id) return true;
    }
  }
  return false;
}

}  // namespace canbridge::bridge
