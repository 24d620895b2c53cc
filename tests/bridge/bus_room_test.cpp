// Exactly once to the bus (issue 14), in process: a gateway and a surface over TCP loopback with
// virtual buses. While a bus cannot take frames, reliable frames for it wait in order, the role
// stops reading the backbone (the peer's resend window becomes the bound) without the link being
// declared dead, and once the bus drains every frame arrives once, in order.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <cstdint>
#include <memory>
#include <vector>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/bridge/loopback_roles.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using test::BusRecorder;
using test::run_until;

constexpr ModuleId kModule = 1;
constexpr canopen::NodeId kLocal = 2, kSurface = 5;
constexpr std::uint32_t kFrames = 3000;  // well above the 1024-frame high watermark

// An SDO upload request carrying a sequence number where the server ignores it.
can::Frame request(std::uint16_t cob, std::uint32_t seq) {
  return can::Frame::standard(cob, {0x40, 0x00, 0x20, 0x00, static_cast<std::uint8_t>(seq),
                                    static_cast<std::uint8_t>(seq >> 8), 0, 0});
}

BackboneTuning quick_tuning() {
  BackboneTuning t;
  t.session.keepalive_interval = 20ms;
  t.session.dead_after = 150ms;
  t.session.retransmit_timeout = 100ms;
  return t;
}

class BusRoom : public ::testing::Test {
 protected:
  void SetUp() override {
    NodeMap map;
    ASSERT_TRUE(map.add_module(kModule, {{kLocal, kSurface}}).empty());
    std::vector<GatewayModule> modules;
    GatewayModule m;
    m.id = kModule;
    m.bus = module_bus.connect("gateway", 16);  // a 16-frame transmit queue, as configured
    modules.push_back(std::move(m));
    gateway = std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules),
                                        quick_tuning());
    ASSERT_TRUE(start_linked_over_loopback(io, surface, *gateway, server, client));
  }

  void TearDown() override {
    if (client) client->stop();
    if (gateway) gateway->stop();
    server->stop();
    surface.stop();
    master.close();
    node.close();
    EXPECT_TRUE(run_until(io, [&] { return master.done() && node.done(); }));
  }

  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module"};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  BusRecorder node{io, module_bus.connect("node")};
  Surface surface{io.get_executor(), "surface", surface_bus.connect("surface", 16),
                  SurfacePolicy{{{"gw", {kModule}, {kSurface}}}, false}, quick_tuning()};
  std::shared_ptr<backbone::TcpServer> server = backbone::TcpServer::create(io.get_executor());
  std::unique_ptr<Gateway> gateway;
  std::shared_ptr<backbone::TcpClient> client;
};

TEST_F(BusRoom, ReliableFramesWaitForTheModuleBusAndArriveOnceInOrder) {
  module_bus.hold(true);  // the module bus takes nothing for now
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    ASSERT_TRUE(master.send(request(0x600 + kSurface, i)));
  }
  // The gateway's bus queue passes its high watermark: it stops reading the surface.
  ASSERT_TRUE(run_until(io, [&] { return gateway->stream().input_paused(); }))
      << gateway->stats_line();
  EXPECT_EQ(gateway->counters().backbone_pauses, 1u);
  // Paused for several times dead_after: the link must stay up on both sides (the gateway's
  // keepalives still reach the surface; the gateway does not count the surface's silence).
  EXPECT_FALSE(run_until(
      io, [] { return false; }, 4 * quick_tuning().session.dead_after));
  EXPECT_TRUE(gateway->connected());
  EXPECT_EQ(surface.gateways_ready(), 1u);
  EXPECT_EQ(gateway->counters().session.dead_links, 0u);
  EXPECT_EQ(surface.counters().session.dead_links, 0u);
  const GatewayCounters paused = gateway->counters();
  EXPECT_LT(paused.frames_received, kFrames) << "the backbone was not held back";
  EXPECT_TRUE(node.frames.empty());

  module_bus.hold(false);  // the bus drains
  ASSERT_TRUE(run_until(
      io, [&] { return node.frames.size() >= kFrames; }, 20s))
      << node.frames.size() << " frames; " << gateway->stats_line();
  ASSERT_EQ(node.frames.size(), kFrames);
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    ASSERT_EQ(node.frames[i], request(0x600 + kLocal, i)) << "frame " << i;
  }
  const GatewayCounters g = gateway->counters();
  EXPECT_FALSE(gateway->stream().input_paused());
  EXPECT_EQ(g.bus_refused, 0u);
  EXPECT_GT(g.bus_waited, 1024u);
  EXPECT_EQ(g.to_buses, kFrames);
  EXPECT_EQ(g.session.dead_links, 0u);
  EXPECT_EQ(surface.counters().outbox.reliable_refused, 0u);
  EXPECT_NE(gateway->stats_line().find("bus-waited " + std::to_string(g.bus_waited)),
            std::string::npos)
      << gateway->stats_line();
}

TEST_F(BusRoom, ReliableFramesWaitForTheSurfaceBusAndArriveOnceInOrder) {
  auto emcy = [](std::uint16_t cob, std::uint32_t seq) {
    return can::Frame::standard(cob, {0x00, 0x10, 0x01, static_cast<std::uint8_t>(seq),
                                      static_cast<std::uint8_t>(seq >> 8)});
  };
  surface_bus.hold(true);
  for (std::uint32_t i = 0; i < kFrames; ++i) ASSERT_TRUE(node.send(emcy(0x080 + kLocal, i)));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().backbone_pauses == 1; }))
      << surface.stats_line();
  EXPECT_FALSE(run_until(
      io, [] { return false; }, 4 * quick_tuning().session.dead_after));
  EXPECT_TRUE(gateway->connected());
  EXPECT_EQ(surface.gateways_ready(), 1u);
  EXPECT_EQ(surface.counters().session.dead_links, 0u);
  EXPECT_EQ(gateway->counters().session.dead_links, 0u);
  EXPECT_TRUE(master.frames.empty());

  surface_bus.hold(false);
  ASSERT_TRUE(run_until(
      io, [&] { return master.frames.size() >= kFrames; }, 20s))
      << master.frames.size() << " frames; " << surface.stats_line();
  ASSERT_EQ(master.frames.size(), kFrames);
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    ASSERT_EQ(master.frames[i], emcy(0x080 + kSurface, i)) << "frame " << i;
  }
  const SurfaceCounters c = surface.counters();
  EXPECT_EQ(c.bus_refused, 0u);
  EXPECT_GT(c.bus_waited, 1024u);
  EXPECT_EQ(c.to_bus, kFrames);
  EXPECT_EQ(gateway->counters().outbox.reliable_refused, 0u);
  EXPECT_NE(surface.stats_line().find("bus-waited " + std::to_string(c.bus_waited)),
            std::string::npos)
      << surface.stats_line();
}

}  // namespace
}  // namespace canbridge::bridge
