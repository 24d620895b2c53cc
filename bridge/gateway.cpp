#include "bridge/gateway.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "bridge/bus_state_log.hpp"
#include "bridge/delivery_class.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway_claims.hpp"
#include "bridge/gateway_statistics.hpp"
#include "bridge/role_statistics_fill.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

namespace {
// Unix time minus steady time, now: converts kernel receive times (Unix) to the steady clock.
std::chrono::nanoseconds steady_to_unix_offset() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::system_clock::now().time_since_epoch() -
      std::chrono::steady_clock::now().time_since_epoch());
}

std::vector<GatewayPdopWork::Module> pdop_modules_of(const std::vector<GatewayModule>& modules) {
  std::vector<GatewayPdopWork::Module> pdop;
  for (const GatewayModule& m : modules) {
    pdop.push_back({m.id, m.reassemble_pdop, m.pdop_reassembly, m.pdop_segmentation});
  }
  return pdop;
}

std::vector<GatewayRemote::Module> remote_modules_of(const std::vector<GatewayModule>& modules) {
  std::vector<GatewayRemote::Module> remote;
  for (const GatewayModule& m : modules) remote.push_back({m.id, m.lss, m.census});
  return remote;
}

// How long after start the census waits: every node running its application with a heartbeat
// has sent one by then (producer times are rarely above 1 s), so only silent ids are asked.
constexpr std::chrono::milliseconds kCensusAfter{2000};
// A node answers the census at once; an absent node never does.
constexpr std::chrono::milliseconds kCensusTimeout{200};

std::vector<ModuleId> module_ids_of(const std::vector<GatewayModule>& modules) {
  std::vector<ModuleId> ids;
  for (const GatewayModule& m : modules) ids.push_back(m.id);
  return ids;
}
}  // namespace

Gateway::Gateway(asio::any_io_executor executor, std::string name, NodeMap map,
                 std::vector<GatewayModule> modules, BackboneTuning tuning,
                 GatewayRemoteOptions remote)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      map_(std::move(map)),
      modules_(std::move(modules)),
      loop_guards_(modules_.size()),
      remote_(map_, node_table_, remote_modules_of(modules_), remote,
              [this](std::size_t m, canopen::NodeId node) { return sdo_.transfer_open(m, node); }),
      deadlines_(executor_),
      node_events_(name_, map_, module_ids_of(modules_),
                   [this](std::size_t m) {
                     // The surface's PDO Packet relay learns the pdop nodes' ids from PdopNodes.
                     if (pdop_.reassembles(m)) pdop_.announce_nodes();
                   }),
      reports_(map_, node_table_, module_ids_of(modules_), tuning.outbox.max_node_event_payloads),
      pdop_(map_, pdop_modules_of(modules_), name_),
      tuning_(tuning),
      outbox_(tuning_.outbox),
      stream_(tuning_.session, stream_handlers()) {
  identity_.role = v1::Hello::ROLE_GATEWAY;
  identity_.expected_peer = v1::Hello::ROLE_SURFACE;
  identity_.name = name_;
  identity_.session_id = backbone::random_session_id();
  for (std::size_t m = 0; m < modules_.size(); ++m) add_module_bus(m);
  // The surface checks these against every other gateway's and routes its frames by them.
  identity_.application = encode_claims(claims_of(map_));
  deadlines_.add(
      "node table", [this] { return node_table_.next_deadline(); },
      [this](DeadlineDriver::TimePoint now) {
        node_table_.tick(now, node_events_.sink());
        queue_node_events();
      });
  deadlines_.add(
      "census", [this] { return census_at_; },
      [this](DeadlineDriver::TimePoint now) {
        census_at_.reset();
        ask_silent_nodes(now);
        after_remote_input();
      });
  deadlines_.add(
      "remote services", [this] { return remote_.next_deadline(); },
      [this](DeadlineDriver::TimePoint now) {
        remote_.tick(now);
        after_remote_input();
      });
  if (pdop_.active()) {
    deadlines_.add(
        "PDO Packets", [this] { return pdop_.next_deadline(); },
        [this](DeadlineDriver::TimePoint now) {
          pdop_.tick(now, steady_to_unix_offset());
          write_pdop_frames();
          stream_.wake();
        });
  }
}

backbone::PeerStream::Handlers Gateway::stream_handlers() {
  return {[this](backbone::PayloadSink& sink) { produce(sink); },
          [this](std::span<const std::uint8_t> payload, bool) { on_payload(payload); },
          [this](const v1::Hello& peer) {
            outbox_.set_head_runs(peer.protocol_minor() >= kHeadRunsMinor);
            // The surface may be a new process: it learns the pdop nodes on every link.
            pdop_.announce_nodes();
            // A mere reconnect resumes the reliable stream; a new process learns the nodes.
            if (peer.session_id() != snapshot_surface_) queue_node_snapshot(peer);
          },
          [this] { on_link_dead(); },
          // A new surface process: what was queued for the old one is not replayed.
          [this](const v1::Hello&) { outbox_.discard_queued(); },
          [this](const std::string& payload, backbone::ReliableDrop why) {
            on_payload_dropped(payload, why);
          }};
}

// A remote result is never too old to deliver: it reports what was done and commands nothing,
// and the surface waits for it past a stall or a cut (bridge/remote_request_ledger.hpp). Given up
// for its age (sent or not: the surface waits for it), a write that was done would be reported
// as failed: it goes again, as a new payload; a new surface never asked. Frames stay dropped
// (a late command does harm) and are counted, in frames, by why.
void Gateway::on_payload_dropped(const std::string& payload, backbone::ReliableDrop why) {
  v1::Payload parsed;
  if (!parsed.ParseFromString(payload)) return;
  if (parsed.has_remote_result()) {
    if (why != backbone::ReliableDrop::peer_restart) {
      remote_.resend_result(std::move(*parsed.mutable_remote_result()));
    }
    return;
  }
  std::vector<can::Frame> frames;
  if (!parsed.has_frames() || decode_frame_batch(parsed.frames(), frames) != BatchError::none) {
    return;  // node events, PDO Packets: no frames of a bus
  }
  switch (why) {
    case backbone::ReliableDrop::too_old:
      counters_.session_frames_too_old += frames.size();
      break;
    case backbone::ReliableDrop::too_old_unacked:
      counters_.session_frames_expired_unacked += frames.size();
      break;
    case backbone::ReliableDrop::peer_restart:
      counters_.session_frames_peer_restart += frames.size();
      break;
  }
}

void Gateway::add_module_bus(std::size_t m) {
  node_table_.add_module(map_.modules()[m].profile, modules_[m].heartbeat_lost_after);
  writers_.push_back(std::make_unique<BusWriter>(
      executor_, *modules_[m].bus, backbone_fed_write_options(),
      [this, m](std::span<const can::Frame> frames) { on_written(m, frames); },
      [this](bool) { on_backlog_changed(); }));
  identity_.module_ids.push_back(modules_[m].id);
  if (modules_[m].lss) translator_.route_lss_to(m);
}

Gateway::~Gateway() = default;

void Gateway::start() {
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    log_bus_state_changes(*modules_[m].bus, fmt::format("gateway {}: module {} bus {}", name_,
                                                        modules_[m].id, modules_[m].bus->name()));
    coro::spawn_owned(executor_, read_bus(m), [this, m](const std::string& why) {
      on_task_end("reader of bus " + modules_[m].bus->name(), why);
    });
    writers_[m]->on_end([this, m](const std::string& why) {
      on_task_end("writer of bus " + modules_[m].bus->name(), why);
    });
    writers_[m]->start();
  }
  // A node that booted before the gateway started announced it to nobody: a qd node waiting in
  // its loader sends nothing on its own, nor does an application with its heartbeat off. The
  // census asks the ids still unknown once the others have been heard.
  census_at_ = DeadlineDriver::Clock::now() + kCensusAfter;
  coro::spawn_owned(executor_, deadlines_.run(),
                    [this](const std::string& why) { on_task_end("deadline driver", why); });
}

void Gateway::ask_silent_nodes(DeadlineDriver::TimePoint now) {
  for (const GatewayRemote::CensusAsked& asked : remote_.census(kCensusTimeout, now)) {
    spdlog::info("gateway {}: module {}: asking {} silent id(s) {}", name_,
                 modules_[asked.module_index].id, asked.ids,
                 asked.question == GatewayRemote::CensusQuestion::in_loader
                     ? "whether they wait in their loader"
                     : "for their device type (a node with its heartbeat off is listed)");
  }
}

// A gateway with one loop gone is up but deaf to a bus (or blind to its node table): worse than
// down, because nothing tells the operator. Stop all of it, in order, and say why.
void Gateway::on_task_end(const std::string& task, const std::string& why) {
  if (stopped_) return;
  failure_ = task + " stopped: " + (why.empty() ? "it ended" : why);
  spdlog::error("gateway {}: {}; stopping the gateway", name_, failure_);
  stop();
  if (on_failure_) on_failure_(failure_);
}

void Gateway::write_pdop_frames() {
  for (GatewayPdopWork::BusFrames& out : pdop_.bus_frames()) {
    // Whole, behind what waits for the bus: a gap inside a window the node might not see at all.
    if (!writers_[out.module_index]->write(out.frames, BusWriteQueue::Lane::reliable)) {
      warn_.warn(Warn::kBusRefused,
                 "gateway: bus {} cannot take {} RPDOP fragments at once: dropped (counted)",
                 modules_[out.module_index].bus->name(), out.frames.size());
    }
  }
  pdop_.bus_frames().clear();
}

void Gateway::after_remote_input() {
  for (GatewayRemote::BusFrames& out : remote_.bus_frames()) {
    for (const can::Frame& frame : out.frames) {
      // Frame by frame: a block transfer's sub-block may hold more frames than the bus queue.
      if (!writers_[out.module_index]->write(frame, BusWriteQueue::Lane::reliable)) {
        warn_.warn(Warn::kBusRefused,
                   "gateway: bus {} refused a frame of a remote service: dropped (counted; the "
                   "transfer times out)",
                   modules_[out.module_index].bus->name());
      }
    }
  }
  remote_.bus_frames().clear();
  // The census's finds: listed like nodes that booted into their loader.
  if (const auto found = remote_.take_found_in_loader(); !found.empty()) {
    const auto now = NodeTable::Clock::now();
    for (const GatewayRemote::FoundInLoader& f : found) {
      node_table_.on_found_in_loader(f.module_index, f.local, now, node_events_.sink());
    }
    queue_node_events();
  }
  deadlines_.reschedule();
  stream_.wake();
}

bool Gateway::refuse_colliding_sdo(std::size_t m, const can::Frame& local) {
  const GatewayRemote::MasterCollision collision = remote_.on_master_frame(m, local);
  if (!collision.refused) return false;
  ++counters_.sdo_collisions;
  warn_.warn(Warn::kSdoCollision,
             "gateway {}: an SDO request from the surface to module {} node {} met the gateway's "
             "own transfer: answered with abort 0x08000021 (counted as sdo-collisions)",
             name_, modules_[m].id, local.id - canopen::cob::sdo_rx);
  // As if from the node: the same path as its responses (translated, value tracking sees it).
  if (collision.abort) queue_for_surface(m, *collision.abort, LoopGuard::Clock::now());
  return true;
}

void Gateway::after_node_input() {
  queue_node_events();
  deadlines_.reschedule();
}

void Gateway::queue_node_events() {
  const std::optional<std::string> claims = node_events_.settle();
  if (node_events_.empty()) return;
  if (claims) identity_.application = *claims;  // the next hello carries them too
  for (const NodeEvent& e : node_events_.events()) {
    sdo_.on_node_event(e);
    remote_.on_node_event(e, e.at);  // a boot-up confirms a set-node-id the gateway sent
  }
  if (reports_.queue_events(node_events_.events(), claims.value_or(std::string()))) {
    warn_events_dropped();
  }
  node_events_.clear();
  stream_.wake();
}

void Gateway::warn_events_dropped() {
  warn_.warn(Warn::kEventsDropped,
             "gateway: node events dropped: the backbone link is down too long (counted)");
}

void Gateway::queue_node_snapshot(const v1::Hello& surface) {
  snapshot_surface_ = surface.session_id();
  const NodeReportQueue::Snapshot sent = reports_.queue_snapshot();
  if (sent.dropped) warn_events_dropped();
  spdlog::info(
      "gateway {}: surface {} has not heard from this gateway: its {} node(s) sent ({} lost)",
      name_, backbone::describe_peer(surface), sent.nodes, sent.lost);
  stream_.wake();
}

void Gateway::produce(backbone::PayloadSink& sink) {
  // PDO Packets and their reports: reliable, in order, ahead of frames (a packet is data that
  // already waited for all its fragments).
  pdop_.produce(sink, tuning_.session.resend_buffer_bytes);
  // Results of services the surface asked for: few and small (a flash image goes the other way).
  remote_.produce(sink);
  // Events first: they are few, and a master's view of a node should not lag its frames.
  while (std::string* payload = reports_.front()) {
    if (sink.room() < payload->size() + 16 || !sink.reliable_room(payload->size())) break;
    sink.send_reliable(std::move(*payload));
    reports_.pop();
  }
  outbox_.produce(sink);
}

void Gateway::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  if (link_) {
    link_->close();
    old_links_framing_ += link_->message_link()->counters().deframer;
    old_links_tx_bytes_ += link_->message_link()->counters().tx_bytes;
    const backbone::LinkCounters old = link_->message_link()->counters();
    old_links_.rx_bytes += old.rx_bytes;
    old_links_.rx_messages += old.rx_messages;
    old_links_.tx_writes += old.tx_writes;
  }
  link_ = backbone::SessionLink::create(std::move(link), identity_, tuning_.session, &stream_,
                                        nullptr, counters_.session, &session_log_);
  link_->start();
}

void Gateway::stop() {
  stopped_ = true;
  deadlines_.stop();
  if (link_) link_->close();
  stream_.close_link();
  for (auto& w : writers_) w->stop();
  for (auto& m : modules_) m.bus->close();
}

asio::awaitable<std::error_code> Gateway::read_bus(std::size_t module_index) {
  can::Bus& bus = *modules_[module_index].bus;
  std::vector<can::Frame> batch;
  batch.reserve(512);
  for (;;) {
    batch.clear();
    if (std::error_code ec = co_await bus.receive_batch(batch)) co_return ec;
    on_bus_batch(module_index, batch);
  }
}

void Gateway::on_bus_batch(std::size_t module_index, std::span<const can::Frame> batch) {
  counters_.from_buses += batch.size();
  const bool reassembles = pdop_.reassembles(module_index);
  const auto now = LoopGuard::Clock::now();
  const auto clock_offset = reassembles ? steady_to_unix_offset() : std::chrono::nanoseconds{};
  for (const can::Frame& frame : batch) {
    // Error frames: bus state, counted by the bus itself.
    if (frame.is_error() || drop_echo(module_index, frame, now)) continue;
    const std::size_t events_before = node_events_.events().size();
    note_bus_frame(module_index, frame, now);
    // The node's answers to the gateway's own transfer: the runner's, never the master's.
    if (remote_.on_bus_frame(module_index, frame, now)) continue;
    if (reassembles) {
      // In bus order: a boot-up ends the node's packets before its next fragment arrives.
      for (const NodeEvent& e : node_events_.events().subspan(events_before)) {
        pdop_.on_node_event(e, now);
      }
      const bool taken = pdop_.on_bus_frame(module_index, frame, now, clock_offset);
      write_pdop_frames();
      if (taken) continue;
    }
    queue_for_surface(module_index, frame, now);
  }
  after_node_input();  // reschedules the deadline driver for the PDOP work too
  remote_.tick(now);   // a master's transfer may have ended: a waiting request starts
  after_remote_input();
}

// A frame this gateway wrote, coming back (another bridge, a gateway daemon, a loop in the
// wiring): forwarding it again would start a storm.
bool Gateway::drop_echo(std::size_t module_index, const can::Frame& frame,
                        LoopGuard::Clock::time_point now) {
  if (!loop_guards_[module_index].is_echo(frame, now)) return false;
  ++counters_.echoes_dropped;
  return true;
}

void Gateway::note_bus_frame(std::size_t module_index, const can::Frame& frame,
                             LoopGuard::Clock::time_point now) {
  node_table_.on_bus_frame(module_index, frame, now, node_events_.sink());
  if (frame.id == canopen::cob::nmt && !frame.is_extended()) {  // a master on the module bus
    node_table_.on_nmt_to_bus(module_index, frame, now, node_events_.sink());
  }
  node_events_.follow_renames();  // a confirming boot-up crosses under the node's new id
}

void Gateway::queue_for_surface(std::size_t module_index, const can::Frame& frame,
                                LoopGuard::Clock::time_point now) {
  auto surface = translator_.to_surface(module_index, frame);
  if (!surface) return;
  if (const auto heartbeat = sdo_.from_bus(module_index, frame, *surface)) {
    // The node's heartbeat period, from the write it confirmed (issue 14): never one gap.
    node_table_.note_heartbeat_time(module_index, heartbeat->node, heartbeat->period);
  }
  // A pdop module without reassembly: its TPDO fragments cross as frames, kept in bus order.
  const bool fragments_as_frames =
      map_.modules()[module_index].profile == IdProfile::pdop && !pdop_.reassembles(module_index);
  const GatewayModule& module = modules_[module_index];
  // Queued whether or not the link is up: reliable frames wait (bounded) for the next link.
  if (!outbox_.push(module.id, *surface,
                    {.conflate_pdos = module.conflate_pdos, .pdop_fragments = fragments_as_frames},
                    now)) {
    warn_.warn(Warn::kRefused,
               "gateway: backbone queue full: frames refused (counted per lane; reliable "
               "ones as reliable-refused; the link is too slow or down too long)");
  }
}

// The surface aborts every SDO request in flight when it declares the link dead: one still
// waiting here for its bus must never reach the node.
void Gateway::on_link_dead() {
  sdo_.on_link_dead();
  for (std::size_t m = 0; m < writers_.size(); ++m) {
    // The master's requests go (it saw them aborted); the frames of a transfer the gateway runs
    // itself stay: the link is not part of it, and a lost block segment would stall it.
    sdo_.withdrew(writers_[m]->withdraw([this, m](const can::Frame& waiting) {
      if (!ModuleSdoTracking::withdrawn_at_link_loss(waiting)) return false;
      const auto node = static_cast<canopen::NodeId>(waiting.id - canopen::cob::sdo_rx);
      return !remote_.transferring(m, node);
    }));
  }
}

void Gateway::on_payload(std::span<const std::uint8_t> payload) {
  // Parsed once; the body says what it is.
  decoded_.clear();
  if (!inbound_.ParseFromArray(payload.data(), static_cast<int>(payload.size())) ||
      !(inbound_.has_frames() || inbound_.has_pdop_packets() || inbound_.has_remote_request() ||
        inbound_.has_remote_cancel())) {
    ++counters_.malformed_payloads;
    warn_.warn(Warn::kMalformed,
               "gateway: dropped a backbone payload: not a frame batch (counted)");
    return;
  }
  if (inbound_.has_remote_request() || inbound_.has_remote_cancel()) {
    const auto now = DeadlineDriver::Clock::now();
    if (inbound_.has_remote_request()) {
      remote_.on_request(inbound_.remote_request(), now);
    } else {
      remote_.on_cancel(inbound_.remote_cancel(), now);
    }
    after_remote_input();
    return;
  }
  if (inbound_.has_pdop_packets()) {
    pdop_.on_rpdop_packets(inbound_.pdop_packets(), DeadlineDriver::Clock::now());
    write_pdop_frames();
    deadlines_.reschedule();
    stream_.wake();
    return;
  }
  if (const BatchError error = decode_frame_batch(inbound_.frames(), decoded_);
      error != BatchError::none) {
    ++counters_.malformed_payloads;
    warn_.warn(Warn::kMalformed,
               "gateway: dropped a backbone payload: malformed frame batch ({}) (counted)",
               to_string(error));
    return;
  }
  const v1::FrameBatch& batch = inbound_.frames();
  line_loss_.on_batch(stream_.peer_hello().session_id(), batch.process_frames_sent(),
                      decoded_.size());
  counters_.frames_received += decoded_.size();
  std::optional<std::size_t> only;
  if (batch.module_id() != kAnyModule) {
    only = map_.index_of(batch.module_id());
    if (!only) {
      ++counters_.unknown_module;
      warn_.warn(Warn::kUnknownModule,
                 "gateway: surface sent frames for unknown module {} (counted)", batch.module_id());
      return;
    }
  }
  write_to_buses(only);
}

void Gateway::write_to_buses(std::optional<std::size_t> only) {
  to_bus_.resize(writers_.size());
  for (auto& frames : to_bus_) frames.clear();
  for (const can::Frame& frame : decoded_) {
    const std::uint64_t renames_refused = translator_.dropped(DropReason::rename_refused);
    translator_.to_modules(frame, [&](std::size_t m, can::Frame local) {
      if (only && *only != m) return;
      if (refuse_colliding_sdo(m, local)) return;
      sdo_.to_bus(m, local);
      to_bus_[m].push_back(local);
    });
    if (translator_.dropped(DropReason::rename_refused) != renames_refused) {
      node_events_.on_rename_refused(translator_.rename_refusal(), node_table_,
                                     NodeTable::Clock::now());
    }
  }
  // A bus's frames of the batch at once, in order behind what waits for the bus: one batch send.
  // Only process data may be dropped (counted).
  for (std::size_t m = 0; m < to_bus_.size(); ++m) {
    if (!to_bus_[m].empty() && writers_[m]->write_each(to_bus_[m]) != 0) {
      warn_.warn(Warn::kBusRefused,
                 "gateway: bus {} is backed up: process data dropped (counted as bus-refused)",
                 modules_[m].bus->name());
    }
  }
  after_node_input();
  // A master's transfer may have ended (its abort): a request of the gateway's may start.
  remote_.tick(DeadlineDriver::Clock::now());
  after_remote_input();
}

void Gateway::on_written(std::size_t m, std::span<const can::Frame> frames) {
  const auto now = LoopGuard::Clock::now();
  bool nmt = false;
  for (const can::Frame& frame : frames) {
    loop_guards_[m].wrote(frame, now);
    if (frame.id == canopen::cob::nmt && !frame.is_extended()) {
      node_table_.on_nmt_to_bus(m, frame, now, node_events_.sink());
      nmt = true;
    }
  }
  counters_.to_buses += frames.size();
  // Only then: the bus reader may be in the middle of node_events_ (a segmenter flush).
  if (nmt) after_node_input();
}

void Gateway::on_backlog_changed() {
  const bool backlogged = std::any_of(writers_.begin(), writers_.end(),
                                      [](const auto& w) { return w->queue().backlogged(); });
  if (backlogged == stream_.input_paused()) return;
  if (backlogged) ++counters_.backbone_pauses;
  stream_.pause_input(backlogged);
}

GatewayCounters Gateway::counters() const {
  GatewayCounters c = counters_;
  for (const auto& w : writers_) {
    const BusWriteQueue::Counters& q = w->queue().counters();
    c.bus_waited += q.frames_waited;
    c.bus_waiting_peak = std::max(c.bus_waiting_peak, q.peak_waiting);
    for (std::size_t r = 0; r < BusWriteQueue::kDropReasons; ++r) c.bus_drops[r] += q.dropped[r];
    c.bus_refused += w->queue().dropped() + w->refused();
  }
  c.translation = translator_.drops();
  c.node_events = reports_.counters().events;
  c.node_events_dropped = reports_.counters().events_dropped;
  c.nodes_moved = node_events_.counters().nodes_moved;
  c.node_moves_refused = node_events_.counters().node_moves_refused;
  c.sdo_values_rewritten = sdo_.counters().values_rewritten;
  c.sdo_values_unmapped = sdo_.counters().values_unmapped;
  c.sdo_requests_withdrawn = sdo_.counters().requests_withdrawn;
  c.outbox = outbox_.counters();
  c.process_lost_on_line = line_loss_.lost();
  c.pdop = pdop_.counters();
  c.remote = remote_.counters();
  c.framing = old_links_framing_;
  c.backbone_tx_bytes = old_links_tx_bytes_;
  if (link_) {
    c.framing += link_->message_link()->counters().deframer;
    c.backbone_tx_bytes += link_->message_link()->counters().tx_bytes;
  }
  return c;
}

GatewayStatsSnapshot Gateway::stats_snapshot() const {
  GatewayStatsSnapshot snapshot;
  snapshot.name = name_;
  snapshot.connected = connected();
  snapshot.counters = counters();
  snapshot.queued = outbox_.size();
  snapshot.unacked = stream_.sender().unacked_count();
  if (snapshot.connected) {
    if (auto rtt = stream_.sender().round_trip()) {
      snapshot.round_trip = std::chrono::duration_cast<std::chrono::microseconds>(*rtt);
    }
  }
  snapshot.links = old_links_;
  if (link_) {
    add_link_reads_and_writes(link_->message_link()->counters(), snapshot.links);
  }
  snapshot.nodes = node_table_.counts();
  snapshot.pdop_active = pdop_.active();
  snapshot.pdop_dropped_frames = pdop_.dropped_frames();
  for (const GatewayModule& m : modules_) {
    snapshot.buses.push_back({m.id, m.bus->name(), m.bus->counters(), m.bus->link_up()});
  }
  return snapshot;
}

RoleStatistics Gateway::statistics() const {
  return gateway_statistics(stats_snapshot());
}

std::string Gateway::stats_line() const {
  return gateway_stats_line(stats_snapshot());
}

}  // namespace canbridge::bridge
