#include "app/demo.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <cstdio>
#include <functional>
#include <map>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "canopen/sdo_client.hpp"
#include "coro/spawn_owned.hpp"
#include "sim/node_runner.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;
using namespace std::chrono_literals;

namespace {

// What the surface master learns about one node, from its own bus only.
struct SeenNode {
  unsigned boot_ups = 0;
  std::uint8_t last_state = 0xFF;
  std::uint32_t device_type = 0;
  std::array<std::uint32_t, 4> identity{};
  unsigned sdo_ok = 0;
  unsigned sdo_failed = 0;
  std::string first_error;
};

std::uint32_t le32(const std::vector<std::uint8_t>& b) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < b.size() && i < 4; ++i) v |= std::uint32_t{b[i]} << (8 * i);
  return v;
}

// Runs `condition` checks every 10 ms until true or the deadline: the demo waits for things a
// person would wait for (a link, boot-ups), with a bound so it never hangs.
asio::awaitable<bool> wait_until(std::function<bool()> condition, std::chrono::milliseconds limit) {
  asio::steady_timer timer(co_await asio::this_coro::executor);
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (!condition()) {
    if (std::chrono::steady_clock::now() >= deadline) co_return false;
    timer.expires_after(10ms);
    co_await timer.async_wait(asio::use_awaitable);
  }
  co_return true;
}

}  // namespace

int run_demo(const DemoOptions& options) {
  spdlog::set_level(spdlog::level::warn);  // the demo prints its own report
  asio::io_context io(1);
  auto ex = io.get_executor();

  // Module buses with simulated nodes: module m's node n has serial 1000*m + n.
  std::vector<std::unique_ptr<can::VirtualBus>> module_buses;
  std::vector<std::unique_ptr<can::Bus>> node_ports;
  std::vector<std::unique_ptr<sim::NodeRunner>> runners;
  NodeMap map;
  std::vector<GatewayModule> modules;
  for (unsigned m = 0; m < options.modules; ++m) {
    module_buses.push_back(std::make_unique<can::VirtualBus>(ex, fmt::format("module{}", m)));
    node_ports.push_back(module_buses.back()->connect("nodes"));
    runners.push_back(std::make_unique<sim::NodeRunner>(ex, *node_ports.back()));
    for (unsigned n = 1; n <= options.nodes_per_module; ++n) {
      // One of each kind in turn (the seeds' devices); qd and fpga only exist as nodes 1..31.
      constexpr sim::NodeKind kKinds[] = {sim::NodeKind::cia301, sim::NodeKind::microcanopen,
                                          sim::NodeKind::qd, sim::NodeKind::fpga};
      sim::NodeSpec node;
      node.kind = n <= 31 ? kKinds[(n - 1) % 4] : sim::NodeKind::cia301;
      node.node_id = static_cast<canopen::NodeId>(n);
      // qd: profile 0, the version in the high word (the kind's default); others CiA 401 + m.
      node.device_type = node.kind == sim::NodeKind::qd ? 0 : 0x00000191 + m;
      node.identity = {0x0000ABCD, 0x5EED0000 + m, 0x00010000 + n, 1000 * m + n};
      node.heartbeat_ms = 100;
      runners.back()->add(node);
    }
    if (auto problems = map.add_module(m, NodeMap::default_pairs(m)); !problems.empty()) {
      throw std::runtime_error(problems.front());
    }
    modules.push_back({m, module_buses.back()->connect(fmt::format("module{}", m))});
  }

  can::VirtualBus surface_bus(ex, "surface");
  auto master_port = surface_bus.connect("master");
  Surface surface(ex, "demo-surface", surface_bus.connect("surface"));
  Gateway gateway(ex, "demo-gateway", std::move(map), std::move(modules));
  auto server = backbone::TcpServer::create(ex);
  if (auto ec =
          server->start("127.0.0.1", 0, [&](auto link) { surface.attach(std::move(link)); })) {
    throw std::runtime_error("demo: cannot listen on loopback: " + ec.message());
  }
  auto client = backbone::TcpClient::create(ex, "127.0.0.1", server->port());
  canopen::SdoClientChannel master(ex, *master_port);

  std::map<unsigned, SeenNode> table;  // by surface node id
  master.set_observer([&](const can::Frame& f) {
    if (f.is_extended() || f.id <= 0x700 || f.id > 0x77F || f.len < 1) return;
    SeenNode& n = table[f.id - 0x700];
    n.last_state = f.data[0];
    if (f.data[0] == 0x00) ++n.boot_ups;
  });

  // The kind of the simulated node behind a module's local id (the default map: module m owns
  // surface ids 32m+1..).
  auto kind_of = [&](unsigned module, unsigned local) -> const char* {
    if (module >= runners.size()) return "?";
    for (const auto& node : runners[module]->nodes()) {
      if (node->id() == local) return sim::to_string(node->kind());
    }
    return "?";
  };

  int status = 1;
  bool stopping = false;
  bool failed = false;
  // Ordered shutdown: the clients of the buses first, then the roles, then the links.
  auto shut_down = [&] {
    if (stopping) return;
    stopping = true;
    master.stop();
    for (auto& r : runners) r->stop();
    client->stop();
    server->stop();
    gateway.stop();
    surface.stop();
  };
  // A loop that ends before the scenario is through (a bug, a role that stopped itself) fails the
  // demo at once rather than let it wait for answers that cannot come.
  auto fail = [&](const std::string& what) {
    if (stopping) return;
    std::printf("FAILED: %s\n", what.c_str());
    failed = true;
    shut_down();
  };
  auto on_end = [&](std::string loop) {
    return [&fail, loop = std::move(loop)](const std::string& why) {
      fail(loop + " stopped: " + (why.empty() ? "it ended" : why));
    };
  };
  gateway.on_failure([&](const std::string& why) { fail("gateway: " + why); });
  surface.on_failure([&](const std::string& why) { fail("surface: " + why); });
  std::vector<double> round_trips_ms;
  std::string final_counters;
  auto scenario = [&]() -> asio::awaitable<void> {
    const std::size_t expected = std::size_t{options.modules} * options.nodes_per_module;
    if (!co_await wait_until([&] { return gateway.connected() && surface.gateways_ready() == 1; },
                             5s)) {
      std::printf("FAILED: the backbone did not come up within 5 s\n");
      co_return;
    }
    // Nodes power up once the tunnel is there, so their boot-ups are not dropped as no-link.
    for (std::size_t m = 0; m < runners.size(); ++m) {
      coro::spawn_owned(ex, runners[m]->run(), on_end(fmt::format("the nodes of module {}", m)));
    }
    // A master that joins late resets communication to learn who is there (boot-ups), then
    // starts every node.
    table.clear();
    master_port->send(can::Frame::standard(0x000, {0x82, 0x00}));
    const bool all_booted = co_await wait_until(
        [&] {
          return std::count_if(table.begin(), table.end(), [](const auto& e) {
                   return e.second.boot_ups > 0;
                 }) == static_cast<std::ptrdiff_t>(expected);
        },
        3s);
    master_port->send(can::Frame::standard(0x000, {0x01, 0x00}));
    const bool all_operational = co_await wait_until(
        [&] {
          return std::count_if(table.begin(), table.end(), [](const auto& e) {
                   return e.second.last_state == 0x05;
                 }) == static_cast<std::ptrdiff_t>(expected);
        },
        3s);
    unsigned ok = 0, total = 0;
    for (auto& [surface_id, node] : table) {
      const std::pair<std::uint16_t, std::uint8_t> objects[] = {
          {0x1000, 0}, {0x1018, 1}, {0x1018, 2}, {0x1018, 3}, {0x1018, 4}};
      for (auto [index, sub] : objects) {
        ++total;
        const auto t0 = std::chrono::steady_clock::now();
        canopen::SdoResult r =
            co_await master.upload(static_cast<canopen::NodeId>(surface_id), index, sub, 500ms);
        round_trips_ms.push_back(
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                .count());
        if (!r.ok()) {
          ++node.sdo_failed;
          if (node.first_error.empty()) {
            node.first_error = fmt::format("{:04X}h:{}: {}", index, sub, r.error.message());
          }
          continue;
        }
        ++node.sdo_ok;
        ++ok;
        if (index == 0x1000) node.device_type = le32(r.data);
        if (index == 0x1018) node.identity[sub - 1] = le32(r.data);
      }
    }

    std::printf("\nnode table (as the surface master sees it):\n");
    std::printf("%7s %6s %5s  %-12s  %-16s %8s  %-10s  %-10s %-10s %-10s %6s\n", "surface",
                "module", "local", "kind", "state", "boot-ups", "1000h", "vendor", "product",
                "revision", "serial");
    for (const auto& [surface_id, n] : table) {
      const char* kind = kind_of(surface_id / 32, surface_id % 32);
      std::printf("%7u %6u %5u  %-12s  %-16s %8u  0x%08X  0x%08X 0x%08X 0x%08X %6u%s\n", surface_id,
                  surface_id / 32, surface_id % 32, kind, canopen::nmt_state_name(n.last_state),
                  n.boot_ups, n.device_type, n.identity[0], n.identity[1], n.identity[2],
                  n.identity[3], n.sdo_failed ? ("  SDO failed: " + n.first_error).c_str() : "");
    }
    std::sort(round_trips_ms.begin(), round_trips_ms.end());
    const double median = round_trips_ms.empty() ? 0 : round_trips_ms[round_trips_ms.size() / 2];
    std::printf("\nSDO uploads through the tunnel: %u of %u succeeded, median round trip %.2f ms\n",
                ok, total, median);
    const bool pass = all_booted && all_operational && table.size() == expected && ok == total;
    if (!all_booted)
      std::printf("FAILED: not every node sent a boot-up after reset-communication\n");
    if (!all_operational) std::printf("FAILED: not every node reported operational\n");
    status = pass ? 0 : 1;
    final_counters = "  " + gateway.stats_line() + "\n  " + surface.stats_line();
  };

  std::printf(
      "canbridge demo: %u module(s) x %u simulated node(s) on virtual CAN buses,\n"
      "gateway and surface joined by a TCP backbone on 127.0.0.1:%u\n",
      options.modules, options.nodes_per_module, server->port());
  coro::spawn_owned(ex, master.run(), on_end("the surface master"));
  surface.start();
  gateway.start();
  client->start([&](auto link) { gateway.attach(std::move(link)); });
  coro::spawn_owned(ex, scenario(), [&](const std::string& why) {
    if (!why.empty()) fail("the scenario: " + why);
    shut_down();
  });
  io.run_for(30s);  // bounded: everything above ends well before

  std::printf("\ncounters:\n%s\n", final_counters.c_str());
  if (failed) status = 1;
  std::printf("\n%s\n",
              status == 0 ? "demo OK: every node answered through the tunnel" : "demo FAILED");
  return status;
}

}  // namespace canbridge::bridge
