#include "bridge/surface.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>

#include "bridge/delivery_class.hpp"
#include "bridge/frame_batch_codec.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

// One gateway as the surface knows it, kept across its links so reliable streams resume.
struct Surface::Gateway {
  Gateway(std::string gateway_name, SdoLinkGuard::GatewayId gateway_id,
          const BackboneTuning& tuning, Surface& surface)
      : name(std::move(gateway_name)),
        id(gateway_id),
        outbox(tuning.outbox),
        stream(tuning.session, backbone::PeerStream::Handlers{
                                   [this](backbone::PayloadSink& sink) { outbox.produce(sink); },
                                   [this, &surface](std::span<const std::uint8_t> payload, bool) {
                                     surface.on_payload(*this, payload);
                                   },
                                   nullptr, [this, &surface] { surface.on_gateway_down(*this); }}) {
  }

  std::string name;
  SdoLinkGuard::GatewayId id;
  std::vector<std::uint32_t> modules;  // as announced in its latest accepted hello
  FrameOutbox outbox;
  backbone::PeerStream stream;
};

Surface::Surface(asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
                 BackboneTuning tuning, bool conflate_pdos)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      bus_(std::move(bus)),
      tuning_(tuning),
      conflate_pdos_(conflate_pdos) {
  identity_.role = v1::Hello::ROLE_SURFACE;
  identity_.expected_peer = v1::Hello::ROLE_GATEWAY;
  identity_.name = name_;
  identity_.session_id = backbone::random_session_id();
}

Surface::~Surface() = default;

void Surface::start() {
  asio::co_spawn(executor_, read_bus(), asio::detached);
}

void Surface::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  std::erase_if(links_, [this](const auto& l) {
    if (l->message_link()->is_open()) return false;
    closed_links_framing_ += l->message_link()->counters().deframer;
    return true;
  });
  auto session = backbone::SessionLink::create(
      std::move(link), identity_, tuning_.session, nullptr,
      [this](const v1::Hello& hello, backbone::SessionLink&) { return bind(hello); },
      counters_.session);
  links_.push_back(session);
  session->start();
}

backbone::BindResult Surface::bind(const v1::Hello& hello) {
  backbone::BindResult refused;
  refused.reason = v1::Refusal::DUPLICATE_MODULE;
  const auto& wanted = hello.module_ids();
  for (int i = 0; i < wanted.size(); ++i) {
    if (std::find(wanted.begin(), wanted.begin() + i, wanted[i]) != wanted.begin() + i) {
      refused.detail =
          "gateway '" + hello.name() + "' announces module " + std::to_string(wanted[i]) + " twice";
      return refused;
    }
  }
  for (const auto& [name, other] : gateways_) {
    if (name == hello.name() || !other->stream.up()) continue;
    for (std::uint32_t m : wanted) {
      if (std::find(other->modules.begin(), other->modules.end(), m) != other->modules.end()) {
        refused.detail = "module " + std::to_string(m) + " is already served by gateway '" + name +
                         "', connected to surface '" + name_ + "'; gateway '" + hello.name() +
                         "' refused";
        return refused;
      }
    }
  }
  auto& slot = gateways_[hello.name()];
  if (!slot) {
    slot = std::make_unique<Gateway>(
        hello.name(), static_cast<SdoLinkGuard::GatewayId>(by_id_.size()), tuning_, *this);
    by_id_.push_back(slot.get());
  }
  if (slot->stream.up() && slot->stream.peer_hello().session_id() != hello.session_id()) {
    refused.detail = "a gateway named '" + hello.name() +
                     "' is already connected (another process); names must be unique";
    return refused;
  }
  slot->modules.assign(wanted.begin(), wanted.end());
  return {&slot->stream, {}, {}};
}

void Surface::stop() {
  stopped_ = true;
  for (auto& l : std::vector(links_)) l->close();
  for (auto& [name, g] : gateways_) g->stream.close_link();
  bus_->close();
}

std::size_t Surface::gateways_ready() const {
  return static_cast<std::size_t>(std::count_if(
      gateways_.begin(), gateways_.end(), [](const auto& g) { return g.second->stream.up(); }));
}

asio::awaitable<void> Surface::read_bus() {
  std::vector<can::Frame> batch;
  batch.reserve(512);
  for (;;) {
    batch.clear();
    if (std::error_code ec = co_await bus_->receive_batch(batch)) {
      if (!stopped_) spdlog::error("surface: bus {} stopped: {}", bus_->name(), ec.message());
      co_return;
    }
    counters_.from_bus += batch.size();
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
      const auto verdict = guard_.on_surface_frame(
          frame, [this](SdoLinkGuard::GatewayId g) { return by_id_[g]->stream.up(); });
      if (verdict.reply) send_to_bus(*verdict.reply);
      if (verdict.forward) forward_.push_back(frame);
    }
    // Every known gateway gets the surface traffic (queued while its link is down, so reliable
    // frames reach it exactly once); each routes by COB-ID to its own modules.
    for (auto& [name, gateway] : gateways_) {
      for (const can::Frame& frame : forward_) {
        if (!gateway->outbox.push(kAnyModule, frame, conflate_pdos_) && !is_process_data(frame)) {
          warn_.warn(Warn::kRefused,
                     "surface: backbone queue to gateway '{}' full: reliable frames refused "
                     "(counted as reliable-refused)",
                     name);
        }
      }
      gateway->stream.wake();
    }
  }
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
  counters_.frames_received += decoded_.size();
  for (const can::Frame& frame : decoded_) {
    if (guard_.on_gateway_frame(from.id, frame)) send_to_bus(frame);
  }
}

// Node table events are rare (boot-ups, losses, renames): one log line each is what an operator
// watching a tool string wants to see.
void Surface::on_node_events(Gateway& from, const v1::NodeEvents& events) {
  for (const v1::NodeEvent& e : events.events()) {
    ++counters_.node_events;
    if (e.surface_node() != 0)
      guard_.note_owner(from.id, static_cast<canopen::NodeId>(e.surface_node()));
    const std::string node = fmt::format("gateway '{}' module {} node {} (surface {})", from.name,
                                         e.module_id(), e.local_node(), e.surface_node());
    switch (e.kind()) {
      case v1::NodeEvent::BOOTED:
        spdlog::info("surface: {} booted (boot-up {} seen by the gateway)", node, e.boot_count());
        break;
      case v1::NodeEvent::STATE_CHANGED:
        spdlog::info("surface: {} is {}", node, canopen::nmt_state_name(e.nmt_state()));
        break;
      case v1::NodeEvent::LOST:
        spdlog::warn("surface: {} lost: its heartbeat stopped", node);
        break;
      case v1::NodeEvent::RECOVERED:
        spdlog::info("surface: {} is back ({})", node, canopen::nmt_state_name(e.nmt_state()));
        break;
      case v1::NodeEvent::RENAMED:
        spdlog::info("surface: {} renamed from node {} (surface {})", node, e.previous_local_node(),
                     e.previous_surface_node());
        break;
      case v1::NodeEvent::RENAME_UNCONFIRMED:
        spdlog::warn("surface: {}: set-node-id sent, no boot-up on the new id in time", node);
        break;
      case v1::NodeEvent::DISCOVERED:
        spdlog::info("surface: {} found ({})", node, canopen::nmt_state_name(e.nmt_state()));
        break;
      case v1::NodeEvent::LOADER_BOOTED:
        spdlog::info("surface: {} is in its loader", node);
        break;
      default:
        spdlog::debug("surface: {}: node event of unknown kind {}", node,
                      static_cast<int>(e.kind()));
        break;
    }
  }
}

void Surface::send_to_bus(const can::Frame& frame) {
  if (bus_->send(frame)) {
    loop_guard_.wrote(frame, LoopGuard::Clock::now());
    ++counters_.to_bus;
  } else {
    ++counters_.bus_refused;
    warn_.warn(Warn::kBusRefused, "surface: bus {} refused a frame (transmit queue full; counted)",
               bus_->name());
  }
}

// A master waiting on one of the gateway's nodes must not wait for a timeout of its own.
void Surface::on_gateway_down(Gateway& gateway) {
  if (stopped_) return;
  // The master is told below that these requests failed: the node must never execute them
  // later, when the link returns.
  gateway.outbox.withdraw_queued_sdo_requests();
  gateway.stream.edit_unacked([&](std::string& payload) {
    counters_.sdo_requests_withdrawn_unacked += withdraw_sdo_requests(payload);
  });
  for (const can::Frame& abort : guard_.on_gateway_down(gateway.id)) send_to_bus(abort);
}

SurfaceCounters Surface::counters() const {
  SurfaceCounters c = counters_;
  c.sdo_aborted = guard_.counters().aborted_at_once + guard_.counters().aborted_in_flight;
  c.sdo_late_responses_dropped = guard_.counters().late_responses_dropped;
  c.framing = closed_links_framing_;
  for (const auto& l : links_) c.framing += l->message_link()->counters().deframer;
  for (const auto& [name, g] : gateways_) {
    const OutboxCounters o = g->outbox.counters();
    c.outbox.queued += o.queued;
    c.outbox.conflated += o.conflated;
    c.outbox.process_dropped += o.process_dropped;
    c.outbox.reliable_refused += o.reliable_refused;
    c.outbox.frames_sent += o.frames_sent;
    c.outbox.batches_sent += o.batches_sent;
    c.outbox.sdo_requests_withdrawn += o.sdo_requests_withdrawn;
  }
  return c;
}

std::string Surface::stats_line() const {
  const SurfaceCounters c = counters();
  const can::BusCounters b = bus_->counters();
  std::string s = fmt::format(
      "surface {}: {}/{} gateway(s) up, bus->backbone {} frames, backbone->bus {}, conflated {}, "
      "process-dropped {}, reliable-refused {}, reliable sent {} resent {}, dead-links {}, "
      "refusals {}/{}, sdo-aborted-link-down {} (withdrawn {}, late answers dropped {}), "
      "echoes-dropped {}, "
      "bus-refused {}, "
      "malformed {}, unknown-module {}, node-events {}; "
      "{} rx {} tx {} "
      "kernel-drops {} {}",
      name_, gateways_ready(), gateways_.size(), c.outbox.frames_sent, c.to_bus, c.outbox.conflated,
      c.outbox.process_dropped, c.outbox.reliable_refused, c.session.reliable_sent,
      c.session.reliable_resent, c.session.dead_links, c.session.refusals_sent,
      c.session.refusals_received, c.sdo_aborted,
      c.outbox.sdo_requests_withdrawn + c.sdo_requests_withdrawn_unacked,
      c.sdo_late_responses_dropped, c.echoes_dropped, c.bus_refused,
      c.malformed_payloads + c.session.malformed, c.unknown_module, c.node_events, bus_->name(),
      b.rx_frames, b.tx_frames, b.rx_dropped_kernel, can::to_string(b.state));
  return s;
}

}  // namespace canbridge::bridge
