#include "bridge/surface.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "bridge/bus_state_log.hpp"
#include "bridge/delivery_class.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway_claims.hpp"
#include "bridge/node_event_text.hpp"
#include "bridge/role_statistics_fill.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

namespace {

// A request in flight at a cut waits for its answer until four fifths of its master's time-out
// have passed: the abort then still reaches the master before its own time-out would.
SdoLinkGuard::Options guard_options(std::chrono::milliseconds master_sdo_timeout) {
  return {.transfer_open_for = master_sdo_timeout, .answer_wait = master_sdo_timeout * 4 / 5};
}

}  // namespace

Surface::Surface(asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
                 SurfacePolicy policy, BackboneTuning tuning, bool conflate_pdos,
                 RpdopRelayOptions rpdop_relay)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      bus_(std::move(bus)),
      tuning_(tuning),
      conflate_pdos_(conflate_pdos),
      table_(name_, policy.gateways, policy.require_authenticated_peers),
      guard_(guard_options(policy.master_sdo_timeout)),
      pdop_(rpdop_relay),
      deadlines_(executor_),
      writer_(
          executor_, *bus_, backbone_fed_write_options(),
          [this](std::span<const can::Frame> frames) {
            const auto now = LoopGuard::Clock::now();
            for (const can::Frame& frame : frames) loop_guard_.wrote(frame, now);
            counters_.to_bus += frames.size();
          },
          [this](bool backlogged) { on_bus_backlog(backlogged); }) {
  by_id_.resize(table_.gateways().size(), nullptr);
  identity_.role = v1::Hello::ROLE_SURFACE;
  identity_.expected_peer = v1::Hello::ROLE_GATEWAY;
  identity_.name = name_;
  identity_.session_id = backbone::random_session_id();
  deadlines_.add(
      "RPDOP relay", [this] { return pdop_.next_deadline(); },
      [this](DeadlineDriver::TimePoint now) {
        pdop_.tick(now);
        flush_relay();
      });
  deadlines_.add(
      "SDO answers due", [this] { return guard_.next_deadline(); },
      [this](DeadlineDriver::TimePoint now) {
        const auto withdraw = [this](canopen::NodeId node) {
          const auto owner = guard_.owner_of(node);
          if (owner && *owner < by_id_.size() && by_id_[*owner] != nullptr) {
            withdraw_sdo_requests_to(*by_id_[*owner], node);
          }
        };
        for (const can::Frame& abort : guard_.on_time(now, withdraw)) send_to_bus(abort);
      });
}

Surface::~Surface() = default;

void Surface::start() {
  log_bus_state_changes(*bus_, fmt::format("surface {}: bus {}", name_, bus_->name()));
  coro::spawn_owned(executor_, read_bus(), [this](const std::string& why) {
    on_task_end("reader of bus " + bus_->name(), why);
  });
  coro::spawn_owned(executor_, deadlines_.run(),
                    [this](const std::string& why) { on_task_end("deadline driver", why); });
  writer_.on_end(
      [this](const std::string& why) { on_task_end("writer of bus " + bus_->name(), why); });
  writer_.start();
}

// A surface with one loop gone is up but deaf to its bus: worse than down, because nothing tells
// the operator. Stop all of it, in order, and say why.
void Surface::on_task_end(const std::string& task, const std::string& why) {
  if (stopped_) return;
  failure_ = task + " stopped: " + (why.empty() ? "it ended" : why);
  spdlog::error("surface {}: {}; stopping the surface", name_, failure_);
  stop();
  if (on_failure_) on_failure_(failure_);
}

void Surface::flush_relay() {
  SurfacePdopWork::Output& out = pdop_.flush([this](SurfacePdopWork::GatewayId g) {
    return g < by_id_.size() && by_id_[g] != nullptr && by_id_[g]->stream.up();
  });
  for (auto& [gateway, payload] : out.payloads) {
    by_id_[gateway]->rpdop_out.push_back(std::move(payload));
    by_id_[gateway]->stream.wake();
  }
  for (const can::Frame& ack : out.frames) send_to_bus(ack);
  deadlines_.reschedule();
}

SurfacePdopWork::From Surface::pdop_from(const Gateway& gateway) const {
  return {gateway.id, gateway.name, gateway.modules,
          [this, id = gateway.id](canopen::NodeId node) { return table_.speaks_for(id, node); }};
}

void Surface::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  std::erase_if(links_, [this](const auto& l) {
    if (l->message_link()->is_open()) return false;
    const backbone::LinkCounters closed = l->message_link()->counters();
    closed_links_framing_ += closed.deframer;
    closed_links_.rx_bytes += closed.rx_bytes;
    closed_links_.rx_messages += closed.rx_messages;
    closed_links_.tx_bytes += closed.tx_bytes;
    closed_links_.tx_writes += closed.tx_writes;
    return true;
  });
  auto session = backbone::SessionLink::create(
      std::move(link), identity_, tuning_.session, nullptr,
      [this](const v1::Hello& hello, backbone::SessionLink& session_link) {
        return bind(hello, session_link);
      },
      counters_.session, &session_log_);
  links_.push_back(session);
  session->start();
}

SurfaceGateway::Events Surface::gateway_events() {
  return {
      [this](Gateway& from, std::span<const std::uint8_t> payload) { on_payload(from, payload); },
      [this](Gateway& gateway) { table_.set_connected(gateway.id, true); },
      [this](Gateway& gateway) { on_gateway_down(gateway); },
      // The nodes the old process reported are its no more (the new one reports them again
      // as it hears them).
      [this](Gateway& gateway) {
        node_states_.forget(gateway.id);
        on_gateway_restart(gateway);
      },
      [this](const std::string& payload, backbone::ReliableDrop why) {
        on_payload_dropped(payload, why);
      },
      [this](const can::Frame& frame, backbone::ReliableDrop why) {
        on_frame_dropped(frame, why);
      }};
}

backbone::BindResult Surface::bind(const v1::Hello& hello, backbone::SessionLink& link) {
  GatewayTable::Hello wanted{hello.name(),
                             hello.session_id(),
                             {hello.module_ids().begin(), hello.module_ids().end()},
                             std::nullopt,
                             link.authenticated_peer()};
  GatewayTable::Admission admission;
  if (!hello.application().empty()) {
    wanted.claims = decode_claims(hello.application());
  }
  if (!hello.application().empty() && !wanted.claims) {
    admission.refusal =
        "gateway '" + hello.name().substr(0, 64) + "' sent claims the surface cannot read";
    admission.to_peer = wanted.authenticated_peer.empty() ? "refused" : admission.refusal;
    admission.stranger = true;
  } else {
    admission = table_.admit(wanted);
  }
  if (!admission.id) {
    // The details stay here: a peer that proved nothing learns no names, modules or ids.
    if (admission.stranger) {
      ++counters_.refused_strangers;
      warn_.warn(Warn::kStranger,
                 "surface {}: refused a peer: {} (later refusals of unknown or unproven peers "
                 "only counted as refused-strangers)",
                 name_, admission.refusal);
    } else if (!admission.repeated) {
      spdlog::warn("surface {}: refused a gateway: {}", name_, admission.refusal);
    }
    const bool detailed = admission.to_peer != "refused";
    return {nullptr, detailed ? v1::Refusal::DUPLICATE_MODULE : v1::Refusal::REASON_UNSPECIFIED,
            std::move(admission.to_peer), admission.repeated || admission.stranger};
  }
  if (by_id_[*admission.id] == nullptr) {
    auto gateway =
        std::make_unique<Gateway>(hello.name(), *admission.id, tuning_, gateway_events());
    by_id_[*admission.id] = gateway.get();
    if (writer_.queue().backlogged()) gateway->stream.pause_input(true);
    gateways_[hello.name()] = std::move(gateway);
  }
  Gateway& gateway = *by_id_[*admission.id];
  gateway.modules = std::move(wanted.modules);
  // Its nodes are its from now on, seen or not: an SDO request to one is tracked (and aborted
  // if the link drops) even before the node has sent anything.
  if (wanted.claims) guard_.note_claims(gateway.id, *wanted.claims);
  if (on_link_bound_) on_link_bound_(*link.message_link());
  return {&gateway.stream, {}, {}, false};
}

void Surface::stop() {
  stopped_ = true;
  for (auto& l : std::vector(links_)) l->close();
  for (auto& [name, g] : gateways_) g->stream.close_link();
  deadlines_.stop();
  writer_.stop();
  bus_->close();
}

std::size_t Surface::gateways_ready() const {
  return static_cast<std::size_t>(std::count_if(
      gateways_.begin(), gateways_.end(), [](const auto& g) { return g.second->stream.up(); }));
}

asio::awaitable<std::error_code> Surface::read_bus() {
  std::vector<can::Frame> batch;
  batch.reserve(512);
  for (;;) {
    batch.clear();
    if (std::error_code ec = co_await bus_->receive_batch(batch)) co_return ec;
    counters_.from_bus += batch.size();
    if (monitor_) monitor_(batch, 0, false);
    if (gateways_.empty()) {
      counters_.dropped_no_gateway += batch.size();
      warn_.warn(Warn::kNoGateway,
                 "surface: no gateway has connected yet: surface frames are dropped (counted)");
      continue;
    }
    // SDO requests to nodes whose gateway link is down are answered here, with an abort, and
    // go no further.
    forward_.clear();
    const auto now = LoopGuard::Clock::now();
    for (const can::Frame& frame : batch) {
      if (frame.is_error()) continue;
      if (loop_guard_.is_echo(frame, now)) {  // ours, coming back: never forwarded again
        ++counters_.echoes_dropped;
        continue;
      }
      // RPDOP to a pdop node behind a gateway: the relay acknowledges the master and forwards
      // whole packets.
      if (pdop_.on_bus_frame(frame, now)) continue;
      const auto verdict = guard_.on_surface_frame(
          frame,
          [this](SdoLinkGuard::GatewayId g) {
            return by_id_[g] != nullptr && by_id_[g]->stream.up();
          },
          now);
      if (verdict.reply) send_to_bus(*verdict.reply);
      if (verdict.forward) forward_.push_back(frame);
    }
    // A frame goes to the gateway claiming its node (queued while that link is down, so reliable
    // frames reach it exactly once), broadcasts to every known gateway.
    for (const can::Frame& frame : forward_) {
      const GatewayTable::Route route = table_.route(frame);
      if (route.kind == GatewayTable::Route::one) {
        if (by_id_[route.gateway] != nullptr) forward_to(*by_id_[route.gateway], frame, now);
        continue;
      }
      bool sent = false;
      for (Gateway* gateway : by_id_) {
        if (gateway == nullptr) continue;
        if (route.kind == GatewayTable::Route::all ||
            !table_.gateways()[gateway->id].claims.has_value()) {
          forward_to(*gateway, frame, now);
          sent = true;
        }
      }
      if (!sent && route.kind == GatewayTable::Route::unclaimed) {
        ++counters_.dropped_unclaimed;
        warn_.warn(Warn::kUnclaimed,
                   "surface: frame 0x{:03X} addresses a node no gateway claims: not forwarded "
                   "(counted as unclaimed)",
                   frame.id);
      }
    }
    for (Gateway* gateway : by_id_) {
      if (gateway != nullptr) gateway->stream.wake();
    }
    flush_relay();
  }
}

void Surface::forward_to(Gateway& gateway, const can::Frame& frame,
                         LoopGuard::Clock::time_point now) {
  // RPDOP fragments to a node whose packets cross as frames: in bus order, never conflated.
  const DeliveryOptions delivery{
      .conflate_pdos = conflate_pdos_,
      .pdop_fragments = pdop_.fragments_as_frames(static_cast<canopen::NodeId>(frame.id))};
  if (gateway.outbox.push(kAnyModule, frame, delivery, now)) return;
  warn_.warn(Warn::kRefused,
             "surface: backbone queue to gateway '{}' full: frames refused (counted per lane; "
             "reliable ones as reliable-refused)",
             gateway.name);
  // The master must not wait for an answer that cannot come.
  if (auto abort = guard_.on_not_forwarded(frame)) send_to_bus(*abort);
}

void Surface::on_payload(Gateway& from, std::span<const std::uint8_t> payload) {
  if (!inbound_.ParseFromArray(payload.data(), static_cast<int>(payload.size()))) {
    ++counters_.malformed_payloads;
    warn_.warn(Warn::kMalformed, "surface: dropped a backbone payload: not a payload (counted)");
    return;
  }
  switch (inbound_.body_case()) {
    case v1::Payload::kFrames:
      return on_frames(from, inbound_.frames());
    case v1::Payload::kNodeEvents:
      return on_node_events(from, inbound_.node_events());
    case v1::Payload::kPdopPackets:
      return on_pdop_packets(from, inbound_.pdop_packets());
    case v1::Payload::kPdopReports:
      pdop_.on_reports(pdop_from(from), inbound_.pdop_reports());
      return flush_relay();  // each outcome answers its master
    case v1::Payload::kPdopNodes:
      return pdop_.on_nodes(pdop_from(from), inbound_.pdop_nodes());
    case v1::Payload::kRemoteResult:
    case v1::Payload::kRemoteProgress:
      if (remote_observer_) return remote_observer_(from.id, inbound_);
      break;
    case v1::Payload::kRemoteRequest:  // the surface's to send, never a gateway's
    case v1::Payload::kRemoteCancel:
    case v1::Payload::BODY_NOT_SET:
      break;
  }
  ++counters_.malformed_payloads;
  warn_.warn(Warn::kMalformed,
             "surface: dropped a backbone payload of a kind this version does not know (counted)");
}

void Surface::on_frames(Gateway& from, const v1::FrameBatch& batch) {
  decoded_.clear();
  if (const BatchError err = decode_frame_batch(batch, decoded_); err != BatchError::none) {
    ++counters_.malformed_payloads;
    warn_.warn(Warn::kMalformed,
               "surface: dropped a backbone payload: malformed frame batch ({}) "
               "(counted)",
               to_string(err));
    return;
  }
  if (std::find(from.modules.begin(), from.modules.end(), batch.module_id()) ==
      from.modules.end()) {
    decoded_.clear();
    ++counters_.unknown_module;
    warn_.warn(Warn::kUnknownModule,
               "surface: gateway '{}' sent frames for module {} it did not announce (counted)",
               from.name, batch.module_id());
    return;
  }
  from.line_loss.on_batch(from.stream.peer_hello().session_id(), batch.process_frames_sent(),
                          decoded_.size());
  counters_.frames_received += decoded_.size();
  to_bus_.clear();
  for (const can::Frame& frame : decoded_) {
    // Only its own nodes' COB-IDs: never another module's heartbeat, never NMT or SYNC.
    if (const std::optional<NotItsOwn> why = table_.refuses(from.id, frame)) {
      drop_not_its_own(from, *why, frame.id);
      continue;
    }
    if (guard_.on_gateway_frame(from.id, frame)) to_bus_.push_back(frame);
  }
  // The whole batch at once: one batch send to the bus, one clock read for the loop guard.
  to_bus_accepted_.clear();
  if (writer_.write_each(to_bus_, monitor_ ? &to_bus_accepted_ : nullptr) != 0) {
    warn_.warn(Warn::kBusRefused,
               "surface: bus {} is backed up: process data dropped (counted as bus-refused)",
               bus_->name());
  }
  if (monitor_ && !to_bus_accepted_.empty()) monitor_(to_bus_accepted_, batch.module_id(), true);
}

void Surface::drop_not_its_own(Gateway& from, NotItsOwn why, std::uint32_t cob) {
  const auto r = static_cast<std::size_t>(why);
  ++from.not_its_own[r];
  ++counters_.not_its_own[r];
  if (from.warned_not_its_own.test(r)) return;
  from.warned_not_its_own.set(r);
  spdlog::warn(
      "surface {}: gateway '{}' sent COB-ID 0x{:03X}, not its to send on the surface bus ({}): "
      "dropped (later ones only counted as not-its-own {})",
      name_, from.name, cob, to_string(why), to_string(why));
}

// Node table events are rare (boot-ups, losses, renames): one log line each is what an operator
// watching a tool string wants to see.
void Surface::on_node_events(Gateway& from, const v1::NodeEvents& events) {
  if (events.has_claims()) {
    // A node moved in the gateway's live map: frames to its new surface id go to that gateway.
    const std::optional<GatewayClaims> claims = decode_claims(events.claims().SerializeAsString());
    const std::string why = claims ? table_.update_claims(from.id, *claims) : "unreadable claims";
    if (why.empty()) {
      guard_.note_claims(from.id, *claims);
    } else {
      spdlog::error("surface: gateway '{}' moved a node, but its new claims are refused: {}",
                    from.name, why);
    }
  }
  for (const v1::NodeEvent& e : events.events()) {
    ++counters_.node_events;
    // Only its announced modules: what the surface keeps per gateway stays bounded.
    if (std::find(from.modules.begin(), from.modules.end(), e.module_id()) != from.modules.end()) {
      node_states_.apply(from.id, e);
    }
    if (e.surface_node() != 0 && e.surface_node() <= canopen::kMaxNodeId &&
        table_.speaks_for(from.id, static_cast<canopen::NodeId>(e.surface_node()))) {
      guard_.note_owner(from.id, static_cast<canopen::NodeId>(e.surface_node()));
    }
    // Levels in NodeEventLine::Level order.
    constexpr spdlog::level::level_enum kLevels[] = {spdlog::level::debug, spdlog::level::info,
                                                     spdlog::level::warn};
    const NodeEventLine line = node_event_line(from.name, e);
    spdlog::log(kLevels[static_cast<int>(line.level)], "surface: {}", line.text);
  }
}

// A packet goes on the bus as the node sent it, under its surface id (docs/pdop.md section 2),
// so a master on the surface bus sees PDOP unchanged.
void Surface::on_pdop_packets(Gateway& from, const v1::PdopPackets& packets) {
  const SurfacePdopWork::From source = pdop_from(from);
  for (const v1::PdopPacket& p : packets.packets()) {
    const PdopPacketToBus to_bus = pdop_.on_packet(source, p);
    if (to_bus.verdict == PdopPacketToBus::Verdict::not_its_own) {
      drop_not_its_own(from, NotItsOwn::outside_claims, to_bus.cob_id);
      continue;
    }
    if (to_bus.verdict != PdopPacketToBus::Verdict::to_bus) continue;  // counted there
    // Whole or not at all (a packet with fragments missing can pass a master's toggle check),
    // and in order: a packet waits while the bus's transmit queue cannot take all of it.
    if (!writer_.write(to_bus.fragments, BusWriteQueue::Lane::reliable)) {
      ++counters_.pdop_bus_refused;
      warn_.warn(Warn::kBusRefused,
                 "surface: bus {} cannot hold a PDO Packet of {} fragments: refused (counted as "
                 "pdop bus-refused)",
                 bus_->name(), to_bus.fragments.size());
      continue;
    }
    if (monitor_) monitor_(to_bus.fragments, p.module_id(), true);
    pdop_.delivered(source, p);
    if (pdop_observer_) {
      const std::string& data = p.data();
      const std::span<const std::uint8_t> bytes(reinterpret_cast<const std::uint8_t*>(data.data()),
                                                data.size());
      pdop_observer_({from.name, p.module_id(), static_cast<canopen::NodeId>(p.local_node()),
                      static_cast<canopen::NodeId>(p.surface_node()), p.pdo(), bytes,
                      p.first_fragment_us(), p.duration_us(), p.probable_repeat()});
    }
  }
}

void Surface::send_to_bus(const can::Frame& frame, std::uint32_t module_id) {
  // In order behind what waits for the bus; only process data may be dropped (counted).
  if (!writer_.write(frame, bus_lane_of(frame))) {
    warn_.warn(Warn::kBusRefused,
               "surface: bus {} is backed up: process data dropped (counted as bus-refused)",
               bus_->name());
    return;
  }
  if (monitor_) monitor_(std::span(&frame, 1), module_id, true);
}

bool Surface::send_to_gateway(GatewayTable::GatewayId gateway, std::string payload) {
  if (stopped_ || gateway >= by_id_.size() || by_id_[gateway] == nullptr) return false;
  by_id_[gateway]->rpdop_out.push_back(std::move(payload));
  by_id_[gateway]->stream.wake();
  return true;
}

void Surface::on_bus_backlog(bool backlogged) {
  if (backlogged) ++counters_.backbone_pauses;
  for (auto& [name, gateway] : gateways_) gateway->stream.pause_input(backlogged);
}

// A master waiting on one of the gateway's nodes must not wait for a timeout of its own.
void Surface::on_gateway_down(Gateway& gateway) {
  table_.set_connected(gateway.id, false);
  if (stopped_) return;
  // The master is told below that these requests failed: the node must never execute them
  // later, when the link returns.
  withdraw_sdo_requests_to(gateway, 0);
  for (const can::Frame& abort : guard_.on_gateway_down(gateway.id, deadlines_.now())) {
    send_to_bus(abort);
  }
  deadlines_.reschedule();  // requests that wait for an answer from the next link
}

void Surface::withdraw_sdo_requests_to(Gateway& gateway, std::uint8_t node) {
  // Each withdrawn request is accounted for by how its master gets its answer (the guard's
  // withdrawn counters add up to the withdrawn ones).
  const auto account = [this](const can::Frame& request) { guard_.on_request_withdrawn(request); };
  gateway.outbox.withdraw_queued_sdo_requests(account, node);
  gateway.stream.edit_unacked([&](std::string& payload) {
    counters_.sdo_requests_withdrawn_unacked += withdraw_sdo_requests(payload, account, node);
  });
}

// The old process's answers are gone with it: nothing waits for them any more.
void Surface::on_gateway_restart(Gateway& gateway) {
  for (const can::Frame& abort : guard_.on_gateway_restart(gateway.id, deadlines_.now())) {
    send_to_bus(abort);
  }
}

void Surface::on_frame_dropped(const can::Frame& frame, backbone::ReliableDrop why) {
  switch (why) {
    case backbone::ReliableDrop::too_old:
      ++counters_.reliable_dropped_too_old;
      break;
    case backbone::ReliableDrop::too_old_unacked:
      ++counters_.reliable_expired_unacked;
      break;
    case backbone::ReliableDrop::peer_restart:
      ++counters_.reliable_dropped_gateway_restart;
      break;
  }
  if (!is_sdo_request(frame)) return;
  // Counted by the guard (aborted_discarded).
  if (auto abort = guard_.on_request_discarded(frame, deadlines_.now())) send_to_bus(*abort);
}

void Surface::on_payload_dropped(const std::string& payload, backbone::ReliableDrop why) {
  v1::Payload parsed;
  std::vector<can::Frame> frames;
  if (!parsed.ParseFromString(payload) || !parsed.has_frames() ||
      decode_frame_batch(parsed.frames(), frames) != BatchError::none) {
    return;  // RPDOP packets: the relay times them out and answers the master
  }
  for (const can::Frame& f : frames) on_frame_dropped(f, why);
}

SurfaceCounters Surface::counters() const {
  SurfaceCounters c = counters_;
  const BusWriteQueue::Counters& q = writer_.queue().counters();
  c.bus_waited = q.frames_waited;
  c.bus_waiting_peak = q.peak_waiting;
  c.bus_drops = q.dropped;
  c.bus_refused += writer_.queue().dropped() + writer_.refused();
  c.sdo_guard = guard_.counters();
  c.pdop = pdop_.counters();
  c.framing = closed_links_framing_;
  for (const auto& l : links_) c.framing += l->message_link()->counters().deframer;
  for (const auto& [name, g] : gateways_) {
    c.outbox += g->outbox.counters();
    c.process_lost_on_line += g->line_loss.lost();
    if (std::any_of(g->not_its_own.begin(), g->not_its_own.end(),
                    [](std::uint64_t n) { return n != 0; })) {
      c.not_its_own_by_gateway.emplace_back(name, g->not_its_own);
    }
  }
  return c;
}

SurfaceStatsSnapshot Surface::stats_snapshot() const {
  SurfaceStatsSnapshot snapshot;
  snapshot.name = name_;
  snapshot.counters = counters();
  snapshot.gateways_up = gateways_ready();
  snapshot.gateways_configured = gateways_.size();
  snapshot.gateways_known = by_id_.size();
  snapshot.bus = {0, bus_->name(), bus_->counters(), bus_->link_up()};
  snapshot.links = closed_links_;
  for (const auto& l : links_) {
    const backbone::LinkCounters now = l->message_link()->counters();
    snapshot.links.tx_bytes += now.tx_bytes;
    add_link_reads_and_writes(now, snapshot.links);
  }
  // The slowest gateway's round trip: the one an operator has to worry about.
  for (const auto& [name, g] : gateways_) {
    snapshot.unacked += g->stream.sender().unacked_count();
    if (!g->stream.up()) continue;
    if (auto rtt = g->stream.sender().round_trip()) {
      const auto us = std::chrono::duration_cast<std::chrono::microseconds>(*rtt);
      if (!snapshot.round_trip || us > *snapshot.round_trip) snapshot.round_trip = us;
    }
  }
  // A gateway whose link is down counts its nodes lost (SurfaceNodeStates): the master cannot
  // reach them.
  snapshot.nodes = node_states_.summary([this](SurfaceNodeStates::GatewayId g) {
    return g < by_id_.size() && by_id_[g] != nullptr && by_id_[g]->stream.up();
  });
  return snapshot;
}

RoleStatistics Surface::statistics() const {
  return surface_statistics(stats_snapshot());
}

std::string Surface::stats_line() const {
  return surface_stats_line(stats_snapshot());
}

}  // namespace canbridge::bridge
