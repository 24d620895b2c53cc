// The roles' stats lines print every counter they keep: a loss that is counted but never printed
// (as the surface's dropped-no-gateway once was) is as good as silent.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <memory>
#include <string>
#include <vector>

#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/bridge/scripted_bus.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;

// Labels of every BusCounters, SessionCounters and outbox counter, which both lines carry.
const std::vector<std::string> kSharedLabels = {
    // BusCounters
    " rx ", " tx ", "kernel-drops ", "rx-queue-drops ", "tx-queue-refused ", "tx-errors ",
    "tx-retries ", "error-frames ", "reopens ", "while lost: tx-refused ", " rx-dropped ",
    // SessionCounters
    "session links ", "protocol-errors ", "before-hello ", "keepalives ", "resend-requests ",
    "peer-restarts ", "reliable delivered ", "duplicates ", "unreliable sent ", "lost-on-line ",
    "reliable sent ", "resent ", "dead-links ", "refusals ", "malformed ",
    // OutboxCounters
    "bus->backbone ", "conflated ", "process-dropped ", "reliable-refused ", "queued-total ",
    // frames
    "backbone->bus ", "frames-received ", "process-lost-on-line ", "bus-refused ",
    "echoes-dropped ", "unknown-module ", "node-events "};

void expect_labels(const std::string& line, const std::vector<std::string>& labels) {
  for (const std::string& label : labels) {
    EXPECT_NE(line.find(label), std::string::npos) << "'" << label << "' missing from: " << line;
  }
}

TEST(StatsLine, TheGatewayPrintsEveryCounter) {
  asio::io_context io;
  NodeMap map;
  ASSERT_TRUE(map.add_module(0, NodeMap::default_pairs(0)).empty());
  std::vector<GatewayModule> modules;
  GatewayModule module;
  module.bus = std::make_unique<test::ScriptedBus>(io.get_executor(), "m0",
                                                   test::ScriptedBus::Receive::waits);
  modules.push_back(std::move(module));
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules));
  const std::string line = gateway.stats_line();
  expect_labels(line, kSharedLabels);
  expect_labels(line, {"batches)", "untranslatable ", "sdo-values rewritten ", "unmapped ",
                       "dropped ", "backbone-tx-bytes ", "from-buses ", "sdo-requests-withdrawn "});
}

TEST(StatsLine, TheSurfacePrintsFramesDroppedBeforeAnyGatewayConnected) {
  asio::io_context io;
  can::VirtualBus medium(io.get_executor(), "surface-bus");
  auto master = medium.connect("master");
  Surface surface(io.get_executor(), "s", medium.connect("surface"),
                  SurfacePolicy{{{"gw", {0}, {}}}, false});
  surface.start();
  for (int i = 0; i < 3; ++i) master->send(can::Frame::standard(0x601, {0x40, 0x00, 0x10, 0x00}));
  ASSERT_TRUE(test::run_until(
      io, [&] { return surface.counters().dropped_no_gateway == 3; },
      std::chrono::milliseconds(2000)));
  const std::string line = surface.stats_line();
  EXPECT_NE(line.find("dropped-no-gateway 3"), std::string::npos) << line;
  expect_labels(line, kSharedLabels);
  expect_labels(line, {"from-bus 3", "sdo-aborted-link-down ", "withdrawn ",
                       "late answers dropped ", "pdop packets ", "probable-repeats ",
                       "rpdop forwarded ", "complete ", "failed ", "batches "});
  surface.stop();
  io.run_for(std::chrono::milliseconds(50));
}

}  // namespace
}  // namespace canbridge::bridge
