#include "bridge/gateway.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>
#include <boost/asio/use_awaitable.hpp>

#include "bridge/delivery_class.hpp"
#include "bridge/frame_batch_codec.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

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

Gateway::Gateway(asio::any_io_executor executor, std::string name, NodeMap map,
                 std::vector<GatewayModule> modules, BackboneTuning tuning)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      map_(std::move(map)),
      modules_(std::move(modules)),
      loop_guards_(modules_.size()),
      node_timer_(executor_),
      tuning_(tuning),
      outbox_(tuning_.outbox),
      stream_(
          tuning_.session,
          backbone::PeerStream::Handlers{
              [this](backbone::PayloadSink& sink) { produce(sink); },
              [this](std::span<const std::uint8_t> payload, bool) { on_payload(payload); }, nullptr,
              [this] {
                // The master has seen its transfers aborted (surface link guard): whatever
                // the nodes still send belongs to no transfer the trackers should follow.
                for (auto& module : sdo_trackers_) {
                  for (auto& tracker : module) tracker.reset();
                }
              }}) {
  identity_.role = v1::Hello::ROLE_GATEWAY;
  identity_.expected_peer = v1::Hello::ROLE_SURFACE;
  identity_.name = name_;
  identity_.session_id = backbone::random_session_id();
  sdo_trackers_.resize(modules_.size());
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    node_table_.add_module(map_.modules()[m].profile, modules_[m].heartbeat_lost_after);
    identity_.module_ids.push_back(modules_[m].id);
    if (modules_[m].lss) translator_.route_lss_to(m);
    // A value may only name this module's own ids: a COB-ID or node of another bus is not
    // something this node can reach.
    to_local_.push_back({[this, m](std::uint32_t cob) -> std::optional<std::uint32_t> {
                           auto owner = map_.owner_of_surface_cob(cob);
                           if (!owner || owner->module_index != m) return std::nullopt;
                           return owner->local_cob;
                         },
                         [this, m](canopen::NodeId node) -> std::optional<canopen::NodeId> {
                           auto owner = map_.owner_of_surface(node);
                           if (!owner || owner->module_index != m) return std::nullopt;
                           return owner->local;
                         }});
    to_surface_.push_back({[this, m](std::uint32_t cob) -> std::optional<std::uint32_t> {
                             const std::uint16_t surface = map_.surface_cob_of(m, cob);
                             if (surface == 0) return std::nullopt;
                             return surface;
                           },
                           [this, m](canopen::NodeId node) -> std::optional<canopen::NodeId> {
                             const canopen::NodeId surface = map_.surface_of(m, node);
                             if (surface == 0) return std::nullopt;
                             return surface;
                           }});
  }
}

canopen::NodeId Gateway::sdo_node(std::size_t module_index, const can::Frame& frame,
                                  std::uint16_t base) const {
  if (frame.is_extended() || frame.id <= base) return 0;
  const std::uint32_t node = frame.id - base;
  return node <= max_node_id(map_.modules()[module_index].profile)
             ? static_cast<canopen::NodeId>(node)
             : canopen::NodeId{0};
}

void Gateway::count(canopen::sdo::ValueRewrite rewrite) {
  if (rewrite == canopen::sdo::ValueRewrite::rewritten) ++counters_.sdo_values_rewritten;
  if (rewrite == canopen::sdo::ValueRewrite::no_counterpart) ++counters_.sdo_values_unmapped;
}

Gateway::~Gateway() = default;

void Gateway::start() {
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    asio::co_spawn(executor_, read_bus(m), asio::detached);
  }
  asio::co_spawn(executor_, watch_nodes(), asio::detached);
}

asio::awaitable<void> Gateway::watch_nodes() {
  while (!stopped_) {
    node_timer_.expires_at(node_table_.next_deadline().value_or(NodeTable::TimePoint::max()));
    auto [ec] = co_await node_timer_.async_wait(asio::as_tuple(asio::use_awaitable));
    if (stopped_) co_return;
    if (ec) continue;  // cancelled: an earlier deadline appeared; re-arm
    node_table_.tick(NodeTable::Clock::now(), node_events_);
    queue_node_events();
  }
}

void Gateway::after_node_input() {
  queue_node_events();
  const auto deadline = node_table_.next_deadline();
  if (deadline && *deadline < node_timer_.expiry()) node_timer_.cancel();
}

void Gateway::queue_node_events() {
  if (node_events_.empty()) return;
  v1::Payload payload;
  v1::NodeEvents& out = *payload.mutable_node_events();
  for (const NodeEvent& e : node_events_) {
    spdlog::info("gateway {}: {}", name_, to_string(e));
    const auto m = e.module_index;
    // A node that booted or was renamed starts with no SDO transfer open.
    if (e.kind == NodeEvent::Kind::booted || e.kind == NodeEvent::Kind::renamed ||
        e.kind == NodeEvent::Kind::loader_booted) {
      sdo_trackers_[m][e.local].reset();
      if (e.previous_local != 0) sdo_trackers_[m][e.previous_local].reset();
    }
    v1::NodeEvent& o = *out.add_events();
    o.set_kind(to_proto(e.kind));
    o.set_module_id(modules_[m].id);
    o.set_local_node(e.local);
    o.set_surface_node(map_.surface_of(m, e.local));
    o.set_previous_local_node(e.previous_local);
    o.set_previous_surface_node(e.previous_local ? map_.surface_of(m, e.previous_local) : 0);
    o.set_nmt_state(static_cast<std::uint32_t>(e.state));
    o.set_boot_count(e.boot_count);
    const NodeRecord* record = node_table_.node(m, e.local);
    o.set_in_loader(record && record->loader == LoaderState::in_loader);
  }
  const std::size_t events = node_events_.size();
  counters_.node_events += events;
  node_events_.clear();
  // Bounded: a link down for hours must not grow the queue without end. The oldest go first;
  // the surface learns the current state from the next events and from the heartbeats.
  constexpr std::size_t kMaxQueuedEventPayloads = 1024;
  if (events_out_.size() == kMaxQueuedEventPayloads) {
    counters_.node_events_dropped += events_out_.front().events;
    events_out_.pop_front();
    warn_.warn(Warn::kEventsDropped,
               "gateway: node events dropped: the backbone link is down too long (counted)");
  }
  events_out_.push_back({payload.SerializeAsString(), events});
  stream_.wake();
}

void Gateway::produce(backbone::PayloadSink& sink) {
  // Events first: they are few, and a master's view of a node should not lag its frames.
  while (!events_out_.empty()) {
    std::string& payload = events_out_.front().payload;
    if (sink.room() < payload.size() + 16 || !sink.reliable_room(payload.size())) break;
    sink.send_reliable(std::move(payload));
    events_out_.pop_front();
  }
  outbox_.produce(sink);
}

void Gateway::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  if (link_) {
    link_->close();
    old_links_framing_ += link_->message_link()->counters().deframer;
  }
  link_ = backbone::SessionLink::create(std::move(link), identity_, tuning_.session, &stream_,
                                        nullptr, counters_.session);
  link_->start();
}

void Gateway::stop() {
  stopped_ = true;
  node_timer_.cancel();
  if (link_) link_->close();
  stream_.close_link();
  for (auto& m : modules_) m.bus->close();
}

asio::awaitable<void> Gateway::read_bus(std::size_t module_index) {
  GatewayModule& module = modules_[module_index];
  can::Bus& bus = *module.bus;
  std::vector<can::Frame> batch;
  batch.reserve(512);
  for (;;) {
    batch.clear();
    if (std::error_code ec = co_await bus.receive_batch(batch)) {
      if (!stopped_) spdlog::error("gateway: bus {} stopped: {}", bus.name(), ec.message());
      co_return;
    }
    counters_.from_buses += batch.size();
    const auto now = LoopGuard::Clock::now();
    for (const can::Frame& frame : batch) {
      if (frame.is_error()) continue;  // bus state, counted by the bus itself
      // A frame this gateway wrote, coming back (another bridge, a gateway daemon, a loop in
      // the wiring): forwarding it again would start a storm.
      if (loop_guards_[module_index].is_echo(frame, now)) {
        ++counters_.echoes_dropped;
        continue;
      }
      node_table_.on_bus_frame(module_index, frame, now, node_events_);
      if (frame.id == canopen::cob::nmt && !frame.is_extended()) {  // a master on the module bus
        node_table_.on_nmt_to_bus(module_index, frame, now, node_events_);
      }
      auto surface = translator_.to_surface(module_index, frame);
      if (!surface) continue;
      if (const canopen::NodeId node = sdo_node(module_index, frame, canopen::cob::sdo_tx)) {
        count(sdo_trackers_[module_index][node].on_response(*surface, to_surface_[module_index]));
      }
      // Queued whether or not the link is up: reliable frames wait (bounded) for the next link.
      if (!outbox_.push(module.id, *surface, module.conflate_pdos) && !is_process_data(*surface)) {
        warn_.warn(Warn::kRefused,
                   "gateway: backbone queue full: reliable frames refused (counted as "
                   "reliable-refused; the link is too slow or down too long)");
      }
    }
    after_node_input();
    stream_.wake();
  }
}

void Gateway::on_payload(std::span<const std::uint8_t> payload) {
  if (auto error = decode_frame_payload(payload, inbound_, decoded_)) {
    ++counters_.malformed_payloads;
    warn_.warn(Warn::kMalformed, "gateway: dropped a backbone payload: {} (counted)", *error);
    return;
  }
  const v1::FrameBatch& batch = inbound_.frames();
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
  const auto now = LoopGuard::Clock::now();
  for (const can::Frame& frame : decoded_) {
    translator_.to_modules(frame, [&](std::size_t m, can::Frame local) {
      if (only && *only != m) return;
      if (const canopen::NodeId node = sdo_node(m, local, canopen::cob::sdo_rx)) {
        count(sdo_trackers_[m][node].on_request(local, to_local_[m]));
      }
      if (modules_[m].bus->send(local)) {
        loop_guards_[m].wrote(local, now);
        ++counters_.to_buses;
        if (local.id == canopen::cob::nmt && !local.is_extended()) {
          node_table_.on_nmt_to_bus(m, local, now, node_events_);
        }
      } else {
        ++counters_.bus_refused;
        warn_.warn(Warn::kBusRefused,
                   "gateway: bus {} refused a frame (transmit queue full; counted)",
                   modules_[m].bus->name());
      }
    });
  }
  after_node_input();
}

GatewayCounters Gateway::counters() const {
  GatewayCounters c = counters_;
  c.translation = translator_.drops();
  c.outbox = outbox_.counters();
  c.framing = old_links_framing_;
  if (link_) c.framing += link_->message_link()->counters().deframer;
  return c;
}

std::string Gateway::stats_line() const {
  const GatewayCounters c = counters();
  std::uint64_t dropped = 0;
  for (auto d : c.translation) dropped += d;
  const auto& sender = stream_.sender();
  std::string s = fmt::format(
      "gateway {}: link {}, bus->backbone {} frames ({} batches), backbone->bus {}, "
      "untranslatable {}, queued {}, conflated {}, process-dropped {}, reliable-refused {}, "
      "reliable sent {} resent {} unacked {}, dead-links {}, refusals {}/{}, malformed {}, "
      "bus-refused {}, echoes-dropped {}, sdo-values rewritten {} unmapped {}",
      name_, connected() ? "up" : "down", c.outbox.frames_sent, c.outbox.batches_sent, c.to_buses,
      dropped, outbox_.size(), c.outbox.conflated, c.outbox.process_dropped,
      c.outbox.reliable_refused, c.session.reliable_sent, c.session.reliable_resent,
      sender.unacked_count(), c.session.dead_links, c.session.refusals_sent,
      c.session.refusals_received, c.malformed_payloads + c.session.malformed, c.bus_refused,
      c.echoes_dropped, c.sdo_values_rewritten, c.sdo_values_unmapped);
  s += fmt::format("; {}, node-events {} dropped {}", to_string(node_table_.counts()),
                   c.node_events, c.node_events_dropped);
  if (c.framing.frames + c.framing.discarded_bytes != 0) {
    s += fmt::format("; framing: frames {} crc-errors {} discarded-bytes {}", c.framing.frames,
                     c.framing.crc_errors, c.framing.discarded_bytes);
  }
  for (const auto& m : modules_) {
    const can::BusCounters b = m.bus->counters();
    s += fmt::format("; {} rx {} tx {} kernel-drops {} {}", m.bus->name(), b.rx_frames, b.tx_frames,
                     b.rx_dropped_kernel, can::to_string(b.state));
  }
  return s;
}

}  // namespace canbridge::bridge
