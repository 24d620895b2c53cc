// canbridge-sim: runs a rig file's simulated CANopen nodes on SocketCAN interfaces (or on virtual
// buses), for test rigs, benches and demos.
#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <chrono>
#include <exception>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "can/socketcan_bus.hpp"
#include "can/virtual_bus.hpp"
#include "coro/spawn_owned.hpp"
#include "logging/log_setup.hpp"
#include "sim/command_line.hpp"
#include "sim/node_runner.hpp"
#include "sim/rig_file.hpp"

namespace {

namespace asio = boost::asio;
using namespace canbridge;

using Options = sim::SimOptions;

// An error written outside the logger: in the journal format every line has the error priority,
// as the logger's own error lines do.
void print_error(logging::LogFormat format, const std::string& text) {
  std::cerr << logging::prefix_lines(logging::resolve(format), spdlog::level::err, text);
}

int usage_error(const Options& options, const std::string& message) {
  print_error(options.log_format, "canbridge-sim: " + message);
  return 2;
}

struct RunningBus {
  std::string name;
  std::string interface;  // empty: virtual
  std::unique_ptr<can::VirtualBus> virtual_bus;
  std::unique_ptr<can::Bus> bus;
  std::unique_ptr<sim::NodeRunner> runner;
};

asio::awaitable<void> log_stats(std::vector<RunningBus>& buses, unsigned seconds,
                                asio::steady_timer& timer) {
  for (;;) {
    timer.expires_after(std::chrono::seconds(seconds));
    auto [ec] = co_await timer.async_wait(asio::as_tuple(asio::use_awaitable));
    if (ec) co_return;
    for (const auto& b : buses) {
      const auto c = b.bus->counters();
      spdlog::info("bus {}: rx {} tx {} tx-dropped {} rx-dropped {} node-drops {}", b.name,
                   c.rx_frames, c.tx_frames, c.tx_dropped_queue + c.tx_dropped_error,
                   c.rx_dropped_kernel + c.rx_dropped_queue, b.runner->dropped_frames());
    }
  }
}

// Loads the rig and checks that every --bus and every --interface BUS=IF names one of its buses;
// returns the exit status when the program should stop here. A rig file that cannot be loaded is
// exit status 2, as canbridge's own configuration files: the command line named a bad file.
std::optional<int> load(const Options& options, sim::RigSpec& rig) {
  try {
    rig = sim::load_rig(options.rig_path);
  } catch (const std::exception& e) {
    print_error(options.log_format, std::string("canbridge-sim: ") + e.what());
    return 2;
  }
  const auto known = [&](const std::string& name) {
    for (const auto& b : rig.buses) {
      if (b.name == name) return true;
    }
    return false;
  };
  std::string names;
  for (const auto& b : rig.buses) names += (names.empty() ? "" : ", ") + b.name;
  for (const auto& name : options.buses) {
    if (!known(name)) {
      return usage_error(options,
                         "rig " + rig.name + " has no bus " + name + " (it has " + names + ")");
    }
  }
  // An --interface for a bus the rig does not have would be ignored, and the bus it was meant
  // for would run on its file's interface or a virtual bus: refuse it instead.
  for (const auto& [name, interface] : options.interfaces) {
    if (!known(name)) {
      return usage_error(options, "--interface " + name + "=" + interface + ": rig " + rig.name +
                                      " has no bus " + name + " (it has " + names + ")");
    }
  }
  return std::nullopt;
}

// A bus on the interface the command line or the file names, or on a virtual bus; with its
// nodes added (they boot when the runner runs). Throws when the interface cannot be opened.
RunningBus open_bus(asio::io_context& io, const sim::BusSpec& spec, const Options& options) {
  RunningBus running;
  running.name = spec.name;
  running.interface = spec.interface;
  if (const auto it = options.interfaces.find(spec.name); it != options.interfaces.end()) {
    running.interface = it->second;
  }
  if (options.all_virtual) running.interface.clear();
  if (running.interface.empty()) {
    running.virtual_bus = std::make_unique<can::VirtualBus>(io.get_executor(), spec.name);
    running.bus = running.virtual_bus->connect("nodes");
  } else {
    can::SocketCanOptions socket;
    socket.interface = running.interface;
    running.bus = can::SocketCanBus::open(io.get_executor(), socket);
  }
  running.runner = std::make_unique<sim::NodeRunner>(io.get_executor(), *running.bus);
  for (const auto& node : spec.nodes) running.runner->add(node);
  return running;
}

void announce_ready(const std::vector<RunningBus>& buses, std::size_t node_count) {
  for (const auto& b : buses) {
    spdlog::info("bus {} on {}: {} nodes", b.name,
                 b.interface.empty() ? std::string("virtual bus") : b.interface,
                 b.runner->nodes().size());
  }
  std::cout << "canbridge-sim: ready " << node_count << " nodes on " << buses.size() << " buses"
            << std::endl;
}

// Runs the buses until a signal or until a loop ends on its own; returns the exit status.
int run(asio::io_context& io, std::vector<RunningBus>& buses, std::size_t node_count,
        unsigned stats_seconds) {
  asio::steady_timer stats_timer(io);
  asio::signal_set signals(io, SIGINT, SIGTERM);
  bool stopping = false;
  int exit_status = 0;
  // Ordered shutdown: stop the node runners, then close the buses so every loop ends.
  auto stop_all = [&] {
    stopping = true;
    signals.cancel();
    for (auto& b : buses) b.runner->stop();
    for (auto& b : buses) b.bus->close();
    stats_timer.cancel();
  };
  // A loop that ends on its own (a bus gone, a bug) would leave a rig with silent nodes: stop
  // everything and exit non-zero instead.
  auto on_end = [&](const std::string& loop, const std::string& why) {
    if (stopping) return;
    spdlog::error("canbridge-sim: {} stopped: {}; stopping", loop, why.empty() ? "it ended" : why);
    exit_status = 1;
    stop_all();
  };
  for (auto& b : buses) {
    coro::spawn_owned(io, b.runner->run(), [&, name = b.name](const std::string& why) {
      on_end("the nodes of bus " + name, why);
    });
  }
  if (stats_seconds > 0) {
    coro::spawn_owned(io, log_stats(buses, stats_seconds, stats_timer),
                      [&](const std::string& why) { on_end("the stats timer", why); });
  }
  signals.async_wait([&](const boost::system::error_code& ec, int signal) {
    if (ec) return;
    spdlog::info("signal {}: stopping", signal);
    stop_all();
  });
  // The runners boot their nodes on their first turn; announce readiness after that turn.
  asio::post(io, [&] { announce_ready(buses, node_count); });
  io.run();
  return exit_status;
}

}  // namespace

int main(int argc, char** argv) {
  const sim::SimCommandLine command_line = sim::parse_sim_command_line(
      std::vector<std::string>(argv + 1, argv + argc), CANBRIDGE_VERSION);
  if (!command_line.options) {
    std::cout << command_line.output;
    if (!command_line.error.empty()) print_error(logging::LogFormat::automatic, command_line.error);
    return command_line.exit_status;
  }
  const Options& options = *command_line.options;
  logging::setup_logging(
      options.log_format,
      logging::parse_level(options.log_level.value_or("info")).value_or(spdlog::level::info));
  sim::RigSpec rig;
  if (const auto exit_status = load(options, rig)) return *exit_status;

  asio::io_context io(1);
  std::vector<RunningBus> buses;
  std::size_t node_count = 0;
  try {
    for (const auto& spec : rig.buses) {
      if (!options.buses.empty() && options.buses.count(spec.name) == 0) continue;
      buses.push_back(open_bus(io, spec, options));
      node_count += spec.nodes.size();
    }
  } catch (const std::exception& e) {
    print_error(options.log_format, std::string("canbridge-sim: ") + e.what());
    return 1;
  }
  return run(io, buses, node_count, options.stats_seconds);
}
