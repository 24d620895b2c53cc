#include "bridge/gateway.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>

namespace canbridge::bridge {

namespace asio = boost::asio;

Gateway::Gateway(asio::any_io_executor executor, std::string name, NodeMap map,
                 std::vector<GatewayModule> modules, std::size_t max_backlog)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      map_(std::move(map)),
      modules_(std::move(modules)),
      max_backlog_(max_backlog) {}

Gateway::~Gateway() = default;

void Gateway::start() {
  for (std::size_t m = 0; m < modules_.size(); ++m) {
    asio::co_spawn(executor_, read_bus(m), asio::detached);
  }
}

void Gateway::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  if (session_) session_->close();
  v1::Hello hello;
  hello.set_protocol_major(kProtocolMajor);
  hello.set_protocol_minor(kProtocolMinor);
  hello.set_role(v1::Hello::ROLE_GATEWAY);
  hello.set_name(name_);
  std::vector<std::uint32_t> ids;
  for (const auto& m : modules_) {
    hello.add_module_ids(m.id);
    ids.push_back(m.id);
  }
  BackboneSession::Handlers handlers;
  handlers.on_frames = [this](std::uint32_t module_id, std::span<const can::Frame> frames) {
    on_backbone_frames(module_id, frames);
  };
  // Forget the session when its link ends, unless a newer one has replaced it meanwhile.
  handlers.on_closed = [this] {
    if (session_ && session_->is_closed()) session_.reset();
  };
  session_ =
      std::make_shared<BackboneSession>(std::move(link), std::move(hello), v1::Hello::ROLE_SURFACE,
                                        std::move(ids), max_backlog_, counters_.backbone);
  session_->start(std::move(handlers));
}

void Gateway::stop() {
  stopped_ = true;
  if (session_) session_->close();
  for (auto& m : modules_) m.bus->close();
}

asio::awaitable<void> Gateway::read_bus(std::size_t module_index) {
  can::Bus& bus = *modules_[module_index].bus;
  std::vector<can::Frame> batch;
  batch.reserve(512);
  for (;;) {
    batch.clear();
    if (std::error_code ec = co_await bus.receive_batch(batch)) {
      if (!stopped_) spdlog::error("gateway: bus {} stopped: {}", bus.name(), ec.message());
      co_return;
    }
    counters_.from_buses += batch.size();
    const bool up = session_ && session_->ready();
    for (const can::Frame& frame : batch) {
      auto surface = translator_.to_surface(module_index, frame);
      if (!surface) continue;
      if (!up) {
        ++counters_.dropped_no_link;
        warn_.warn(Warn::kNoLink,
                   "gateway: backbone not connected: module frames are dropped (counted)");
        continue;
      }
      session_->queue(module_index, *surface);
    }
    if (up) session_->flush();
  }
}

void Gateway::on_backbone_frames(std::uint32_t module_id, std::span<const can::Frame> frames) {
  std::optional<std::size_t> only;
  if (module_id != kAnyModule) {
    only = map_.index_of(module_id);
    if (!only) {
      ++counters_.backbone.unknown_module;
      warn_.warn(Warn::kUnknownModule,
                 "gateway: surface sent frames for unknown module {} (counted)", module_id);
      return;
    }
  }
  for (const can::Frame& frame : frames) {
    translator_.to_modules(frame, [&](std::size_t m, const can::Frame& local) {
      if (only && *only != m) return;
      if (modules_[m].bus->send(local)) {
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
  return c;
}

std::string Gateway::stats_line() const {
  const GatewayCounters c = counters();
  std::uint64_t dropped = 0;
  for (auto d : c.translation) dropped += d;
  std::string s = fmt::format(
      "gateway {}: link {}, bus->backbone {} frames ({} batches), backbone->bus {}, "
      "untranslatable {}, no-link {}, backlog-full {}, bus-refused {}, malformed {}",
      name_, connected() ? "up" : "down", c.backbone.frames_sent, c.backbone.batches_sent,
      c.to_buses, dropped, c.dropped_no_link, c.backbone.dropped_backlog, c.bus_refused,
      c.backbone.malformed_envelopes + c.backbone.malformed_batches);
  for (const auto& m : modules_) {
    const can::BusCounters b = m.bus->counters();
    s += fmt::format("; {} rx {} tx {} kernel-drops {} {}", m.bus->name(), b.rx_frames, b.tx_frames,
                     b.rx_dropped_kernel, can::to_string(b.state));
  }
  return s;
}

}  // namespace canbridge::bridge
