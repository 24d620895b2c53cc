#include "bridge/surface.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>

#include "bridge/frame_batch_codec.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

Surface::Surface(asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
                 std::size_t max_backlog)
    : executor_(std::move(executor)),
      name_(std::move(name)),
      bus_(std::move(bus)),
      max_backlog_(max_backlog) {}

Surface::~Surface() = default;

void Surface::start() {
  asio::co_spawn(executor_, read_bus(), asio::detached);
}

void Surface::attach(std::shared_ptr<backbone::MessageLink> link) {
  if (stopped_) return link->close();
  v1::Hello hello;
  hello.set_protocol_major(kProtocolMajor);
  hello.set_protocol_minor(kProtocolMinor);
  hello.set_role(v1::Hello::ROLE_SURFACE);
  hello.set_name(name_);
  auto session = std::make_shared<BackboneSession>(
      std::move(link), std::move(hello), v1::Hello::ROLE_GATEWAY,
      std::vector<std::uint32_t>{kAnyModule}, max_backlog_, counters_.backbone);
  BackboneSession* raw = session.get();
  BackboneSession::Handlers handlers;
  handlers.on_frames = [this, raw](std::uint32_t module_id, std::span<const can::Frame> frames) {
    on_gateway_frames(*raw, module_id, frames);
  };
  handlers.on_closed = [this, raw] {
    std::erase_if(sessions_, [raw](const auto& s) { return s.get() == raw; });
  };
  sessions_.push_back(session);
  session->start(std::move(handlers));
}

void Surface::stop() {
  stopped_ = true;
  for (auto& s : std::vector(sessions_)) s->close();
  bus_->close();
}

std::size_t Surface::gateways_ready() const {
  return static_cast<std::size_t>(
      std::count_if(sessions_.begin(), sessions_.end(), [](const auto& s) { return s->ready(); }));
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
    bool any = false;
    // Every ready gateway gets the surface traffic; each routes by COB-ID to its own modules.
    for (auto& session : sessions_) {
      if (!session->ready()) continue;
      any = true;
      for (const can::Frame& frame : batch) session->queue(0, frame);
      session->flush();
    }
    if (!any) {
      counters_.dropped_no_link += batch.size();
      warn_.warn(Warn::kNoLink,
                 "surface: no gateway connected: surface frames are dropped (counted)");
    }
  }
}

void Surface::on_gateway_frames(const BackboneSession& from, std::uint32_t module_id,
                                std::span<const can::Frame> frames) {
  const auto& ids = from.peer_hello().module_ids();
  if (std::find(ids.begin(), ids.end(), module_id) == ids.end()) {
    ++counters_.backbone.unknown_module;
    warn_.warn(Warn::kUnknownModule,
               "surface: gateway '{}' sent frames for module {} it did not announce (counted)",
               from.peer_hello().name(), module_id);
    return;
  }
  for (const can::Frame& frame : frames) {
    if (bus_->send(frame)) {
      ++counters_.to_bus;
    } else {
      ++counters_.bus_refused;
      warn_.warn(Warn::kBusRefused,
                 "surface: bus {} refused a frame (transmit queue full; counted)", bus_->name());
    }
  }
}

std::string Surface::stats_line() const {
  const can::BusCounters b = bus_->counters();
  return fmt::format(
      "surface {}: {} gateway(s), bus->backbone {} frames, backbone->bus {}, no-link {}, "
      "backlog-full {}, bus-refused {}, malformed {}, unknown-module {}; {} rx {} tx {} "
      "kernel-drops {} {}",
      name_, gateways_ready(), counters_.backbone.frames_sent, counters_.to_bus,
      counters_.dropped_no_link, counters_.backbone.dropped_backlog, counters_.bus_refused,
      counters_.backbone.malformed_envelopes + counters_.backbone.malformed_batches,
      counters_.backbone.unknown_module, bus_->name(), b.rx_frames, b.tx_frames,
      b.rx_dropped_kernel, can::to_string(b.state));
}

}  // namespace canbridge::bridge
