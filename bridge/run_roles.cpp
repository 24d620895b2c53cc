#include "bridge/run_roles.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/io_context.hpp>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/ordered_shutdown.hpp"
#include "bridge/periodic_stats.hpp"
#include "bridge/surface.hpp"
#include "can/socketcan_bus.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

namespace {

std::unique_ptr<can::Bus> open_bus(asio::any_io_executor ex, const std::string& interface,
                                   const config::CanOptions& options) {
  can::SocketCanOptions o;
  o.interface = interface;
  o.receive_buffer_bytes = options.receive_buffer_bytes;
  o.transmit_queue_frames = options.transmit_queue_frames;
  o.batch_size = 256;  // the bridge forwards whole batches: bigger drains, fewer wake-ups
  std::error_code ec;
  auto bus = can::SocketCanBus::open(std::move(ex), std::move(o), ec);
  if (!bus)
    throw std::runtime_error("cannot open CAN interface '" + interface + "': " + ec.message());
  return bus;
}

void apply_log_level(const config::LogOptions& log) {
  spdlog::set_level(spdlog::level::from_str(log.level));
}

}  // namespace

int run_gateway(const config::GatewayOptions& options) {
  apply_log_level(options.log);
  asio::io_context io(1);
  NodeMap map;
  std::vector<GatewayModule> modules;
  for (const auto& m : options.modules) {
    auto problems = map.add_module(m.id, m.nodes);  // validated by the loader already
    if (!problems.empty()) throw std::runtime_error(problems.front());
    modules.push_back({m.id, open_bus(io.get_executor(), m.bus, options.can)});
  }
  Gateway gateway(io.get_executor(), options.name, std::move(map), std::move(modules));
  backbone::ClientOptions client_options;
  client_options.backoff_min = options.reconnect_min;
  client_options.backoff_max = options.reconnect_max;
  auto client = backbone::TcpClient::create(io.get_executor(), options.connect.host,
                                            options.connect.port, client_options);
  PeriodicStats stats(io.get_executor(), options.log.stats_interval,
                      [&] { return gateway.stats_line(); });
  OrderedShutdown shutdown(io, [&] {
    stats.stop();
    client->stop();
    gateway.stop();
  });
  gateway.start();
  client->start(
      [&](std::shared_ptr<backbone::MessageLink> link) { gateway.attach(std::move(link)); });
  spdlog::info("gateway {}: {} module(s), connecting to {}", options.name, options.modules.size(),
               options.connect.to_string());
  shutdown.run();
  spdlog::info("{}", gateway.stats_line());
  return 0;
}

int run_surface(const config::SurfaceOptions& options) {
  apply_log_level(options.log);
  asio::io_context io(1);
  Surface surface(io.get_executor(), options.name,
                  open_bus(io.get_executor(), options.bus, options.can));
  auto server = backbone::TcpServer::create(io.get_executor());
  PeriodicStats stats(io.get_executor(), options.log.stats_interval,
                      [&] { return surface.stats_line(); });
  OrderedShutdown shutdown(io, [&] {
    stats.stop();
    server->stop();
    surface.stop();
  });
  surface.start();
  if (std::error_code ec = server->start(
          options.listen.host, options.listen.port,
          [&](std::shared_ptr<backbone::MessageLink> link) { surface.attach(std::move(link)); })) {
    throw std::runtime_error("cannot listen on " + options.listen.to_string() + ": " +
                             ec.message());
  }
  spdlog::info("surface {}: bus {}, listening on {}:{}", options.name, options.bus,
               options.listen.host, server->port());
  shutdown.run();
  spdlog::info("{}", surface.stats_line());
  return 0;
}

}  // namespace canbridge::bridge
