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

// Module m's node n: one of each kind in turn (the seeds' devices), serial 1000*m + n.
sim::NodeSpec demo_node(unsigned module, unsigned local) {
  // qd and fpga only exist as nodes 1..31.
  constexpr sim::NodeKind kKinds[] = {sim::NodeKind::cia301, sim::NodeKind::microcanopen,
                                      sim::NodeKind::qd, sim::NodeKind::fpga};
  sim::NodeSpec node;
  node.kind = local <= 31 ? kKinds[(local - 1) % 4] : sim::NodeKind::cia301;
  node.node_id = static_cast<canopen::NodeId>(local);
  // qd: profile 0, the version in the high word (the kind's default); others CiA 401 + m.
  node.device_type = node.kind == sim::NodeKind::qd ? 0 : 0x00000191 + module;
  node.identity = {0x0000ABCD, 0x5EED0000 + module, 0x00010000 + local, 1000 * module + local};
  node.heartbeat_ms = 100;
  return node;
}

// The gateway side of the rig: one virtual bus per module with its simulated nodes, and the
// default node map. Built before the gateway, which takes the map and the module ports.
struct ModuleRig {
  std::vector<std::unique_ptr<can::VirtualBus>> buses;
  std::vector<std::unique_ptr<can::Bus>> node_ports;
  std::vector<std::unique_ptr<sim::NodeRunner>> runners;
  NodeMap map;
  std::vector<GatewayModule> modules;
};

ModuleRig build_module_rig(asio::any_io_executor ex, const DemoOptions& options) {
  ModuleRig rig;
  for (unsigned m = 0; m < options.modules; ++m) {
    rig.buses.push_back(std::make_unique<can::VirtualBus>(ex, fmt::format("module{}", m)));
    rig.node_ports.push_back(rig.buses.back()->connect("nodes"));
    rig.runners.push_back(std::make_unique<sim::NodeRunner>(ex, *rig.node_ports.back()));
    for (unsigned n = 1; n <= options.nodes_per_module; ++n)
      rig.runners.back()->add(demo_node(m, n));
    if (auto problems = rig.map.add_module(m, NodeMap::default_pairs(m)); !problems.empty()) {
      throw std::runtime_error(problems.front());
    }
    rig.modules.push_back({m, rig.buses.back()->connect(fmt::format("module{}", m))});
  }
  return rig;
}

// The objects the master reads from every node: device type and the four identity entries.
constexpr std::pair<std::uint16_t, std::uint8_t> kReadObjects[] = {
    {0x1000, 0}, {0x1018, 1}, {0x1018, 2}, {0x1018, 3}, {0x1018, 4}};

struct SdoTally {
  unsigned ok = 0;
  unsigned total = 0;
};

// Everything the demo runs, wired once; the scenario steps are its members so each reads as one
// thing a person would check (link up, boot-ups, operational, SDO reads, report).
class DemoRig {
 public:
  DemoRig(asio::io_context& io, const DemoOptions& options);
  DemoRig(const DemoRig&) = delete;
  DemoRig& operator=(const DemoRig&) = delete;

  // Runs the scenario on `io` (bounded) and returns the demo's exit status.
  int run();

 private:
  void watch_heartbeats();
  void watch_failures();
  const char* kind_of(unsigned module, unsigned local) const;
  void shut_down();
  void fail(const std::string& what);
  std::function<void(const std::string&)> on_end(std::string loop);

  asio::awaitable<void> scenario();
  asio::awaitable<bool> wait_for_link();
  void start_nodes();
  asio::awaitable<bool> wait_for_all(std::function<bool(const SeenNode&)> reached);
  asio::awaitable<void> read_node(unsigned surface_id, SeenNode& node, SdoTally& tally);
  void record_read(SeenNode& node, std::uint16_t index, std::uint8_t sub,
                   const canopen::SdoResult& r, SdoTally& tally);
  void print_node_table() const;
  void print_sdo_summary(const SdoTally& tally);

  asio::io_context& io_;
  asio::any_io_executor ex_;
  DemoOptions options_;
  ModuleRig modules_;
  can::VirtualBus surface_bus_;
  std::unique_ptr<can::Bus> master_port_;
  Surface surface_;
  Gateway gateway_;
  std::shared_ptr<backbone::TcpServer> server_;
  std::shared_ptr<backbone::TcpClient> client_;
  canopen::SdoClientChannel master_;

  std::map<unsigned, SeenNode> table_;  // by surface node id
  std::vector<double> round_trips_ms_;
  std::string final_counters_;
  int status_ = 1;
  bool stopping_ = false;
  bool failed_ = false;
};

// The demo's one gateway, on loopback and in this process: plain, its modules by default mapping.
SurfacePolicy demo_policy(const DemoOptions& options) {
  AcceptedGateway gateway{"demo-gateway", {}, {}};
  for (unsigned m = 0; m < options.modules; ++m) gateway.modules.push_back(m);
  return {{gateway}, false};
}

DemoRig::DemoRig(asio::io_context& io, const DemoOptions& options)
    : io_(io),
      ex_(io.get_executor()),
      options_(options),
      modules_(build_module_rig(ex_, options)),
      surface_bus_(ex_, "surface"),
      master_port_(surface_bus_.connect("master")),
      surface_(ex_, "demo-surface", surface_bus_.connect("surface"), demo_policy(options)),
      gateway_(ex_, "demo-gateway", std::move(modules_.map), std::move(modules_.modules)),
      server_(backbone::TcpServer::create(ex_)),
      client_(nullptr),
      master_(ex_, *master_port_) {
  if (auto ec =
          server_->start("127.0.0.1", 0, [this](auto link) { surface_.attach(std::move(link)); })) {
    throw std::runtime_error("demo: cannot listen on loopback: " + ec.message());
  }
  client_ = backbone::TcpClient::create(ex_, "127.0.0.1", server_->port());
  watch_heartbeats();
  watch_failures();
}

// The master's node table comes from heartbeats on its own bus only, as a real master's would.
void DemoRig::watch_heartbeats() {
  master_.set_observer([this](const can::Frame& f) {
    if (f.is_extended() || f.id <= 0x700 || f.id > 0x77F || f.len < 1) return;
    SeenNode& n = table_[f.id - 0x700];
    n.last_state = f.data[0];
    if (f.data[0] == 0x00) ++n.boot_ups;
  });
}

void DemoRig::watch_failures() {
  gateway_.on_failure([this](const std::string& why) { fail("gateway: " + why); });
  surface_.on_failure([this](const std::string& why) { fail("surface: " + why); });
}

// The kind of the simulated node behind a module's local id (the default map: module m owns
// surface ids 32m+1..).
const char* DemoRig::kind_of(unsigned module, unsigned local) const {
  if (module >= modules_.runners.size()) return "?";
  for (const auto& node : modules_.runners[module]->nodes()) {
    if (node->id() == local) return sim::to_string(node->kind());
  }
  return "?";
}

// Ordered shutdown: the clients of the buses first, then the roles, then the links.
void DemoRig::shut_down() {
  if (stopping_) return;
  stopping_ = true;
  master_.stop();
  for (auto& r : modules_.runners) r->stop();
  client_->stop();
  server_->stop();
  gateway_.stop();
  surface_.stop();
}

// A loop that ends before the scenario is through (a bug, a role that stopped itself) fails the
// demo at once rather than let it wait for answers that cannot come.
void DemoRig::fail(const std::string& what) {
  if (stopping_) return;
  std::printf("FAILED: %s\n", what.c_str());
  failed_ = true;
  shut_down();
}

std::function<void(const std::string&)> DemoRig::on_end(std::string loop) {
  return [this, loop = std::move(loop)](const std::string& why) {
    fail(loop + " stopped: " + (why.empty() ? "it ended" : why));
  };
}

asio::awaitable<bool> DemoRig::wait_for_link() {
  co_return co_await wait_until(
      [this] { return gateway_.connected() && surface_.gateways_ready() == 1; }, 5s);
}

// Nodes power up once the tunnel is there, so their boot-ups are not dropped as no-link.
void DemoRig::start_nodes() {
  for (std::size_t m = 0; m < modules_.runners.size(); ++m) {
    coro::spawn_owned(ex_, modules_.runners[m]->run(),
                      on_end(fmt::format("the nodes of module {}", m)));
  }
}

// Waits (bounded) until every expected node in the table has reached `reached`.
asio::awaitable<bool> DemoRig::wait_for_all(std::function<bool(const SeenNode&)> reached) {
  const std::size_t expected = std::size_t{options_.modules} * options_.nodes_per_module;
  co_return co_await wait_until(
      [&] {
        return std::count_if(table_.begin(), table_.end(), [&](const auto& e) {
                 return reached(e.second);
               }) == static_cast<std::ptrdiff_t>(expected);
      },
      3s);
}

asio::awaitable<void> DemoRig::read_node(unsigned surface_id, SeenNode& node, SdoTally& tally) {
  for (auto [index, sub] : kReadObjects) {
    ++tally.total;
    const auto t0 = std::chrono::steady_clock::now();
    canopen::SdoResult r =
        co_await master_.upload(static_cast<canopen::NodeId>(surface_id), index, sub, 500ms);
    round_trips_ms_.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    record_read(node, index, sub, r, tally);
  }
}

// Keeps the first error per node (the rest usually repeat it) and the values read.
void DemoRig::record_read(SeenNode& node, std::uint16_t index, std::uint8_t sub,
                          const canopen::SdoResult& r, SdoTally& tally) {
  if (!r.ok()) {
    ++node.sdo_failed;
    if (node.first_error.empty()) {
      node.first_error = fmt::format("{:04X}h:{}: {}", index, sub, r.error.message());
    }
    return;
  }
  ++node.sdo_ok;
  ++tally.ok;
  if (index == 0x1000) node.device_type = le32(r.data);
  if (index == 0x1018) node.identity[sub - 1] = le32(r.data);
}

void DemoRig::print_node_table() const {
  std::printf("\nnode table (as the surface master sees it):\n");
  std::printf("%7s %6s %5s  %-12s  %-16s %8s  %-10s  %-10s %-10s %-10s %6s\n", "surface", "module",
              "local", "kind", "state", "boot-ups", "1000h", "vendor", "product", "revision",
              "serial");
  for (const auto& [surface_id, n] : table_) {
    const char* kind = kind_of(surface_id / 32, surface_id % 32);
    std::printf("%7u %6u %5u  %-12s  %-16s %8u  0x%08X  0x%08X 0x%08X 0x%08X %6u%s\n", surface_id,
                surface_id / 32, surface_id % 32, kind, canopen::nmt_state_name(n.last_state),
                n.boot_ups, n.device_type, n.identity[0], n.identity[1], n.identity[2],
                n.identity[3], n.sdo_failed ? ("  SDO failed: " + n.first_error).c_str() : "");
  }
}

void DemoRig::print_sdo_summary(const SdoTally& tally) {
  std::sort(round_trips_ms_.begin(), round_trips_ms_.end());
  const double median = round_trips_ms_.empty() ? 0 : round_trips_ms_[round_trips_ms_.size() / 2];
  std::printf("\nSDO uploads through the tunnel: %u of %u succeeded, median round trip %.2f ms\n",
              tally.ok, tally.total, median);
}

asio::awaitable<void> DemoRig::scenario() {
  if (!co_await wait_for_link()) {
    std::printf("FAILED: the backbone did not come up within 5 s\n");
    co_return;
  }
  start_nodes();
  // A master that joins late resets communication to learn who is there (boot-ups), then
  // starts every node.
  table_.clear();
  master_port_->send(can::Frame::standard(0x000, {0x82, 0x00}));
  const bool all_booted = co_await wait_for_all([](const SeenNode& n) { return n.boot_ups > 0; });
  master_port_->send(can::Frame::standard(0x000, {0x01, 0x00}));
  const bool all_operational =
      co_await wait_for_all([](const SeenNode& n) { return n.last_state == 0x05; });
  SdoTally tally;
  for (auto& [surface_id, node] : table_) co_await read_node(surface_id, node, tally);

  print_node_table();
  print_sdo_summary(tally);
  const std::size_t expected = std::size_t{options_.modules} * options_.nodes_per_module;
  const bool pass =
      all_booted && all_operational && table_.size() == expected && tally.ok == tally.total;
  if (!all_booted) std::printf("FAILED: not every node sent a boot-up after reset-communication\n");
  if (!all_operational) std::printf("FAILED: not every node reported operational\n");
  status_ = pass ? 0 : 1;
  final_counters_ = "  " + gateway_.stats_line() + "\n  " + surface_.stats_line();
}

int DemoRig::run() {
  std::printf(
      "canbridge demo: %u module(s) x %u simulated node(s) on virtual CAN buses,\n"
      "gateway and surface joined by a TCP backbone on 127.0.0.1:%u\n",
      options_.modules, options_.nodes_per_module, server_->port());
  coro::spawn_owned(ex_, master_.run(), on_end("the surface master"));
  surface_.start();
  gateway_.start();
  client_->start([this](auto link) { gateway_.attach(std::move(link)); });
  coro::spawn_owned(ex_, scenario(), [this](const std::string& why) {
    if (!why.empty()) fail("the scenario: " + why);
    shut_down();
  });
  io_.run_for(30s);  // bounded: everything above ends well before

  std::printf("\ncounters:\n%s\n", final_counters_.c_str());
  if (failed_) status_ = 1;
  std::printf("\n%s\n",
              status_ == 0 ? "demo OK: every node answered through the tunnel" : "demo FAILED");
  return status_;
}

}  // namespace

int run_demo(const DemoOptions& options) {
  spdlog::set_level(spdlog::level::warn);  // the demo prints its own report
  asio::io_context io(1);
  DemoRig rig(io, options);
  return rig.run();
}

}  // namespace canbridge::bridge
