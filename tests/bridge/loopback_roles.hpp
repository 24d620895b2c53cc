// Starts one Gateway and one Surface and links them, as the in-process role tests need: over
// loopback TCP (the surface listens on an ephemeral port, the gateway's client reconnects
// quickly), or over an in-memory link pair when the test is not about the transport.
#pragma once

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <memory>

#include "backbone/memory_link.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {

// True once both roles report the link ready; `client` is the gateway's (the caller stops it and
// `server` before the roles).
inline bool start_linked_over_loopback(boost::asio::io_context& io, Surface& surface,
                                       Gateway& gateway,
                                       const std::shared_ptr<backbone::TcpServer>& server,
                                       std::shared_ptr<backbone::TcpClient>& client) {
  using namespace std::chrono_literals;
  surface.start();
  gateway.start();
  if (server->start("127.0.0.1", 0, [&surface](auto link) { surface.attach(link); })) return false;
  backbone::ClientOptions options;
  options.backoff_min = 10ms;
  options.backoff_max = 50ms;
  client = backbone::TcpClient::create(io.get_executor(), "127.0.0.1", server->port(), options);
  client->start([g = &gateway](auto link) { g->attach(std::move(link)); });
  return test::run_until(io, [&] { return surface.gateways_ready() == 1 && gateway.connected(); });
}

// Links two started roles over a new in-memory pair (end a the gateway's, end b the surface's);
// closing either end cuts the link, and a later call links them again.
inline backbone::MemoryLinkPair link_in_memory(boost::asio::io_context& io, Surface& surface,
                                               Gateway& gateway) {
  backbone::MemoryLinkOptions options;
  options.name = "backbone";
  auto pair = backbone::make_memory_link_pair(io.get_executor(), options);
  surface.attach(pair.b);
  gateway.attach(pair.a);
  return pair;
}

// Starts both roles and links them in memory; true once both report the link ready.
inline bool start_linked_in_memory(boost::asio::io_context& io, Surface& surface,
                                   Gateway& gateway) {
  surface.start();
  gateway.start();
  link_in_memory(io, surface, gateway);
  return test::run_until(io, [&] { return surface.gateways_ready() == 1 && gateway.connected(); });
}

}  // namespace canbridge::bridge
