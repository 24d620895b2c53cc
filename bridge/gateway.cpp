#include "bridge/gateway.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>

#include "bridge/delivery_class.hpp"
#include "bridge/frame_batch_codec.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

Gateway::Gateway(asio::any_io_executor executor, std::string name, NodeMap map,
                 std::vector<GatewayModule> modules, BackboneTuning tuning)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      map_(std::move(map)),
      modules_(std::move(modules)),
      loop_guards_(modules_.size()),
      tuning_(tuning),
      outbox_(tuning_.outbox),
      stream_(tuning_.session,
              backbone::PeerStream::Handlers{
                  [this](backbone::PayloadSink& sink) { outbox_.produce(sink); },
                  [this](std::span<const std::uint8_t> payload, bool) { on_payload(payload); },
                  nullptr, nullptr}) {
  identity_.role = v1::Hello::ROLE_GATEWAY;
  identity_.expected_peer = v1::Hello::ROLE_SURFACE;
  identity_.name = name_;
  identity_.session_id = backbone::random_session_id();
  for (const auto& m : modules_) identity_.module_ids.push_back(m.id);
}

Gateway::~Gateway() = default;

void Gateway::start() {
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    asio::co_spawn(executor_, read_bus(m), asio::detached);
  }
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
      auto surface = translator_.to_surface(module_index, frame);
      if (!surface) continue;
      // Queued whether or not the link is up: reliable frames wait (bounded) for the next link.
      if (!outbox_.push(module.id, *surface, module.conflate_pdos) && !is_process_data(*surface)) {
        warn_.warn(Warn::kRefused,
                   "gateway: backbone queue full: reliable frames refused (counted as "
                   "reliable-refused; the link is too slow or down too long)");
      }
    }
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
    translator_.to_modules(frame, [&](std::size_t m, const can::Frame& local) {
      if (only && *only != m) return;
      if (modules_[m].bus->send(local)) {
        loop_guards_[m].wrote(local, now);
        ++counters_.to_buses;
      } else {
        ++counters_.bus_refused;
        warn_.warn(Warn::kBusRefused,
                   "gateway: bus {} refused a frame (transmit queue full; counted)",
                   modules_[m].bus->name());
      }
    });
  }
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
      "bus-refused {}, echoes-dropped {}",
      name_, connected() ? "up" : "down", c.outbox.frames_sent, c.outbox.batches_sent, c.to_buses,
      dropped, outbox_.size(), c.outbox.conflated, c.outbox.process_dropped,
      c.outbox.reliable_refused, c.session.reliable_sent, c.session.reliable_resent,
      sender.unacked_count(), c.session.dead_links, c.session.refusals_sent,
      c.session.refusals_received, c.malformed_payloads + c.session.malformed, c.bus_refused,
      c.echoes_dropped);
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
