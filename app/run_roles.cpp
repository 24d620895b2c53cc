#include "app/run_roles.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/io_context.hpp>
#include <filesystem>

#include "app/admission_from_options.hpp"
#include "app/open_file_limit.hpp"
#include "app/ordered_shutdown.hpp"
#include "app/periodic_stats.hpp"
#include "app/plain_warning.hpp"
#include "app/serial_authentication.hpp"
#include "app/service_notifier.hpp"
#include "app/tls_setup.hpp"
#include "app/tuning_from_options.hpp"
#include "backbone/serial_client.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/command_endpoint.hpp"
#include "bridge/gateway.hpp"
#include "bridge/metrics_endpoint.hpp"
#include "bridge/statistics_service.hpp"
#include "bridge/stats_endpoint.hpp"
#include "bridge/surface.hpp"
#include "bridge/surface_remote.hpp"
#include "can/socketcan_bus.hpp"
#include "config/loader.hpp"

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

backbone::SerialOptions serial_options(const config::SerialLineOptions& line,
                                       const config::GatewayOptions* gateway) {
  backbone::SerialOptions o;
  o.device = line.device;
  o.baud = line.baud;
  o.hardware_flow_control = line.hardware_flow_control;
  // 8N1: ten bits on the line per byte. The writer stays at most a few ms ahead of the line.
  o.link.line_bytes_per_second = line.baud / 10;
  if (gateway) {
    o.backoff_min = gateway->reconnect_min;
    o.backoff_max = gateway->reconnect_max;
  }
  return o;
}

void apply_log_level(const config::LogOptions& log) {
  spdlog::set_level(spdlog::level::from_str(log.level));
}

// The configured modules on their buses, their nodes added to `map`.
std::vector<GatewayModule> open_modules(asio::any_io_executor ex,
                                        const config::GatewayOptions& options, NodeMap& map) {
  std::vector<GatewayModule> modules;
  for (const auto& m : options.modules) {
    auto problems = map.add_module(m.id, m.nodes, m.profile);  // validated by the loader already
    if (!problems.empty()) throw std::runtime_error(problems.front());
    GatewayModule module;
    module.id = m.id;
    module.bus = open_bus(ex, m.bus, options.can);
    module.conflate_pdos = m.conflate_pdos;
    module.lss = options.lss_module == m.id;
    module.heartbeat_lost_after = m.heartbeat_lost_after;
    module.census = m.census;
    module.reassemble_pdop = m.reassemble_pdop;
    module.pdop_reassembly = m.pdop_reassembly;
    module.pdop_segmentation = m.pdop_segmentation;
    modules.push_back(std::move(module));
  }
  return modules;
}

std::shared_ptr<backbone::TcpClient> tcp_client(asio::any_io_executor ex,
                                                const config::GatewayOptions& options) {
  backbone::ClientOptions client_options;
  client_options.backoff_min = options.reconnect_min;
  client_options.backoff_max = options.reconnect_max;
  client_options.upgrade = gateway_link_upgrade(options);
  if (options.session.tcp_crc_framing) {
    client_options.link.framing = backbone::LinkFraming::cobs_crc32c;
  }
  return backbone::TcpClient::create(ex, options.connect.host, options.connect.port,
                                     client_options);
}

// Who the surface binds: its configured `gateways:`, and whether a link must prove an identity
// (every auth mode but plain).
SurfacePolicy surface_policy(const config::SurfaceOptions& options) {
  SurfacePolicy policy;
  for (const config::AcceptedGatewayOptions& g : options.gateways) {
    policy.gateways.push_back(
        {g.name, g.modules, {g.surface_nodes.begin(), g.surface_nodes.end()}});
  }
  policy.require_authenticated_peers = options.auth.mode != config::AuthMode::plain;
  policy.master_sdo_timeout = options.master_sdo_timeout;
  return policy;
}

// The surface's listener under admission control: the surface tells it which links its sessions
// bound (no longer pending, counted against max_links), and it has descriptors for a flood.
std::shared_ptr<backbone::TcpServer> admitting_server(asio::any_io_executor ex,
                                                      const config::SurfaceOptions& options,
                                                      backbone::ServerOptions server_options,
                                                      Surface& surface) {
  server_options.admission = admission_limits(options);
  auto server = backbone::TcpServer::create(std::move(ex), server_options);
  surface.on_link_bound([weak = std::weak_ptr(server)](const backbone::MessageLink& link) {
    if (auto s = weak.lock()) s->admitted(link);
  });
  const auto& limits = server_options.admission;
  spdlog::info(
      "surface {}: admission: {} pending handshakes, {} ms handshake timeout, {} links; {} open "
      "files",
      options.name, limits.max_pending_handshakes, limits.handshake_timeout.count(),
      limits.max_links, raise_open_file_limit());
  return server;
}

// The Unix socket's directory must be there before the endpoint binds: a clear start error
// beats a bind error naming a path (systemd: RuntimeDirectory=canbridge makes /run/canbridge).
void check_socket_directory(const std::string& socket,
                            const std::string& key = "command_endpoint.unix_socket") {
  if (socket.empty()) return;
  const std::filesystem::path dir = std::filesystem::path(socket).parent_path();
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    throw std::runtime_error(key + " " + socket + ": directory " + dir.string() +
                             " does not exist (create it, owned by the surface's user, or set "
                             "RuntimeDirectory=canbridge in the systemd unit)");
  }
}

// The optional Prometheus endpoint on the role's loop (`metrics:`); null when not configured.
std::unique_ptr<MetricsEndpoint> metrics_endpoint(asio::any_io_executor ex,
                                                  const std::optional<config::MetricsOptions>& o,
                                                  StatisticsService& statistics) {
  if (!o) return nullptr;
  MetricsEndpointOptions options;
  options.address = o->listen.host;
  options.port = o->listen.port;
  return std::make_unique<MetricsEndpoint>(std::move(ex), options,
                                           [&statistics] { return statistics.prometheus(); });
}

}  // namespace

int run_gateway(const config::GatewayOptions& options, const HangupReloadSource& reload_source) {
  apply_log_level(options.log);
  warn_if_plain(options);
  asio::io_context io(1);
  NodeMap map;
  std::vector<GatewayModule> modules = open_modules(io.get_executor(), options, map);
  BackboneTuning tuning =
      make_tuning(options.session, options.serial ? options.serial->baud / 10 : 0);
  tuning.session.authenticator = serial_authenticator(options);
  Gateway gateway(io.get_executor(), options.name, std::move(map), std::move(modules), tuning,
                  options.remote);
  auto attach = [&](std::shared_ptr<backbone::MessageLink> link) {
    gateway.attach(std::move(link));
  };
  // Exactly one of the two (the loader checks it).
  std::shared_ptr<backbone::TcpClient> tcp;
  std::shared_ptr<backbone::SerialClient> serial;
  if (options.serial) {
    serial = backbone::SerialClient::create(io.get_executor(),
                                            serial_options(*options.serial, &options));
  } else {
    tcp = tcp_client(io.get_executor(), options);
  }
  StatisticsService statistics(io.get_executor(), [&] { return gateway.statistics(); });
  std::unique_ptr<StatsEndpoint> stats_endpoint;
  if (!options.stats_endpoint.empty()) {
    check_socket_directory(options.stats_endpoint, "stats_endpoint");
    stats_endpoint = std::make_unique<StatsEndpoint>(io.get_executor(),
                                                     StatsEndpointOptions{options.stats_endpoint},
                                                     [&statistics] { return statistics.json(); });
  }
  auto metrics = metrics_endpoint(io.get_executor(), options.metrics, statistics);
  PeriodicStats stats(io.get_executor(), options.log.stats_interval,
                      [&] { return statistics.line(); });
  ServiceNotifier notifier(io.get_executor());  // systemd: Type=notify, WatchdogSec=
  ReloadOnHangup reload(
      io.get_executor(), reload_source, options.log,
      [](std::string_view text, const std::string& file) {
        return config::parse_gateway(text, file).log;
      },
      [&](std::chrono::seconds interval) { stats.set_interval(interval); });
  OrderedShutdown shutdown(io, [&] {
    notifier.stopping();
    reload.stop();
    stats.stop();
    statistics.stop();
    if (stats_endpoint) stats_endpoint->stop();
    if (metrics) metrics->stop();
    if (tcp) tcp->stop();
    if (serial) serial->stop();
    gateway.stop();
  });
  // A gateway that stopped itself (a loop ended or threw) takes the process down in order.
  gateway.on_failure([&](const std::string&) { shutdown.trigger(); });
  gateway.start();
  statistics.start();
  if (stats_endpoint) stats_endpoint->start();  // throws a start error (socket in use, ...)
  if (metrics) metrics->start();                // throws a start error (port in use, ...)
  if (tcp) tcp->start(attach);
  if (serial) serial->start(attach);
  spdlog::info("gateway {}: {} module(s), backbone {}", options.name, options.modules.size(),
               options.serial ? "serial " + options.serial->device + " at " +
                                    std::to_string(options.serial->baud) + " bit/s"
                              : "tcp " + options.connect.to_string());
  // Ready: the module buses are open and the backbone client is connecting.
  notifier.ready("gateway " + options.name + ": " + std::to_string(options.modules.size()) +
                 " module(s) open, backbone connecting");
  shutdown.run();
  spdlog::info("{}", gateway.stats_line());
  if (!gateway.failure().empty()) {
    spdlog::error("gateway {}: exiting after a failure: {}", options.name, gateway.failure());
    return 1;
  }
  return 0;
}

int run_surface(const config::SurfaceOptions& options, const HangupReloadSource& reload_source) {
  apply_log_level(options.log);
  warn_if_plain(options);
  asio::io_context io(1);
  std::size_t slowest_line = 0;  // bytes/s; 0 while no serial line
  for (const auto& line : options.serial) {
    const std::size_t rate = line.baud / 10;
    if (slowest_line == 0 || rate < slowest_line) slowest_line = rate;
  }
  BackboneTuning tuning = make_tuning(options.session, slowest_line);
  tuning.session.authenticator = serial_authenticators(options);
  const SurfacePolicy policy = surface_policy(options);
  Surface surface(io.get_executor(), options.name,
                  open_bus(io.get_executor(), options.bus, options.can), policy, tuning,
                  options.conflate_pdos, options.rpdop_relay);
  auto attach = [&](std::shared_ptr<backbone::MessageLink> link) {
    surface.attach(std::move(link));
  };
  SurfaceRemote remote(io.get_executor(), surface, policy.gateways, options.remote);
  std::unique_ptr<CommandEndpoint> endpoint;
  if (options.command_endpoint) {
    check_socket_directory(options.command_endpoint->unix_socket);
    endpoint =
        std::make_unique<CommandEndpoint>(io.get_executor(), *options.command_endpoint, remote);
  }
  std::shared_ptr<backbone::TcpServer> server;
  if (!options.listen.host.empty()) {
    backbone::ServerOptions server_options;
    server_options.upgrade = surface_link_upgrade(options);
    if (options.session.tcp_crc_framing) {
      server_options.link.framing = backbone::LinkFraming::cobs_crc32c;
    }
    server = admitting_server(io.get_executor(), options, server_options, surface);
  }
  std::vector<std::shared_ptr<backbone::SerialClient>> lines;
  for (const auto& line : options.serial) {
    lines.push_back(
        backbone::SerialClient::create(io.get_executor(), serial_options(line, nullptr)));
  }
  StatisticsService statistics(io.get_executor(), [&] { return surface.statistics(); });
  if (endpoint) endpoint->serve_stats([&statistics] { return statistics.json(); });
  auto metrics = metrics_endpoint(io.get_executor(), options.metrics, statistics);
  PeriodicStats stats(io.get_executor(), options.log.stats_interval,
                      [&] { return statistics.line(); });
  ServiceNotifier notifier(io.get_executor());  // systemd: Type=notify, WatchdogSec=
  ReloadOnHangup reload(
      io.get_executor(), reload_source, options.log,
      [](std::string_view text, const std::string& file) {
        return config::parse_surface(text, file).log;
      },
      [&](std::chrono::seconds interval) { stats.set_interval(interval); });
  OrderedShutdown shutdown(io, [&] {
    notifier.stopping();
    reload.stop();
    stats.stop();
    statistics.stop();
    if (metrics) metrics->stop();
    // Operators first: no new request once the backbone goes.
    if (endpoint) endpoint->stop();
    if (server) server->stop();
    for (auto& line : lines) line->stop();
    // Open requests end (operation_canceled) before the surface they ride on stops.
    remote.stop();
    surface.stop();
  });
  // A surface that stopped itself (a loop ended or threw) takes the process down in order.
  surface.on_failure([&](const std::string&) { shutdown.trigger(); });
  surface.start();
  statistics.start();
  if (metrics) metrics->start();  // throws a start error (port in use, ...)
  if (server) {
    if (std::error_code ec = server->start(options.listen.host, options.listen.port, attach)) {
      throw std::runtime_error("cannot listen on " + options.listen.to_string() + ": " +
                               ec.message());
    }
    spdlog::info("surface {}: bus {}, listening on {}:{}", options.name, options.bus,
                 options.listen.host, server->port());
  }
  for (std::size_t i = 0; i < lines.size(); ++i) {
    lines[i]->start(attach);
    spdlog::info("surface {}: serial line {} at {} bit/s", options.name, options.serial[i].device,
                 options.serial[i].baud);
  }
  if (endpoint) {
    endpoint->start();  // throws a start error (socket in use, not loopback, ...)
    const CommandEndpointOptions& e = *options.command_endpoint;
    spdlog::info("surface {}: command endpoint on {}{}", options.name,
                 e.unix_socket.empty() ? std::string("no Unix socket") : e.unix_socket,
                 e.tcp_port != 0
                     ? " and tcp " + e.tcp_address + ":" + std::to_string(endpoint->tcp_port())
                     : std::string());
  }
  // Ready: the bus is open, the listener accepts, the serial lines and the endpoint are up.
  notifier.ready("surface " + options.name + ": bus " + options.bus + " open, backbone " +
                 (server ? "listening" : "on serial lines"));
  shutdown.run();
  spdlog::info("{}", surface.stats_line());
  if (!surface.failure().empty()) {
    spdlog::error("surface {}: exiting after a failure: {}", options.name, surface.failure());
    return 1;
  }
  return 0;
}

}  // namespace canbridge::bridge
