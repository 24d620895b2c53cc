// One error policy for the roles' loops: a bus reader that throws or whose bus is gone for good
// stops the whole role in order and reports why (the process then exits non-zero), instead of
// leaving a role that is up but no longer reads its bus. A stop asked for is no failure.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <memory>
#include <string>
#include <vector>

#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "routing/node_map.hpp"
#include "tests/bridge/scripted_bus.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using test::ScriptedBus;

// A gateway with two modules: module 0 on a healthy bus (its reader waits), module 1 on a bus
// whose receive does what `second` says.
struct GatewayUnderTest {
  GatewayUnderTest(asio::io_context& io, ScriptedBus::Receive second) {
    NodeMap map;
    std::vector<GatewayModule> modules;
    for (ModuleId id : {0u, 1u}) {
      EXPECT_TRUE(map.add_module(id, NodeMap::default_pairs(id)).empty());
      auto bus = std::make_unique<ScriptedBus>(io.get_executor(), "bus" + std::to_string(id),
                                               id == 0 ? ScriptedBus::Receive::waits : second);
      buses.push_back(bus.get());
      GatewayModule module;
      module.id = id;
      module.bus = std::move(bus);
      modules.push_back(std::move(module));
    }
    gateway =
        std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules));
    gateway->on_failure([this](const std::string& why) { reports.push_back(why); });
  }
  std::vector<ScriptedBus*> buses;  // owned by the gateway
  std::unique_ptr<Gateway> gateway;
  std::vector<std::string> reports;
};

TEST(RoleFailure, AGatewayBusReaderThatThrowsStopsTheGatewayAndSaysWhy) {
  asio::io_context io;
  GatewayUnderTest g(io, ScriptedBus::Receive::throws);
  g.gateway->start();
  io.run_for(std::chrono::milliseconds(200));
  ASSERT_EQ(g.reports.size(), 1u);
  EXPECT_EQ(g.reports[0], "reader of bus bus1 stopped: scripted receive failure");
  EXPECT_EQ(g.gateway->failure(), g.reports[0]);
  // Stopped in order: the healthy module's bus is closed too, so no half-alive gateway remains.
  EXPECT_TRUE(g.buses[0]->closed());
  EXPECT_TRUE(g.buses[1]->closed());
  EXPECT_TRUE(io.stopped());  // every loop of the gateway ended
}

TEST(RoleFailure, AGatewayBusGoneForGoodStopsTheGateway) {
  asio::io_context io;
  GatewayUnderTest g(io, ScriptedBus::Receive::fails);
  g.gateway->start();
  io.run_for(std::chrono::milliseconds(200));
  ASSERT_EQ(g.reports.size(), 1u);
  EXPECT_EQ(g.reports[0], "reader of bus bus1 stopped: " +
                              std::make_error_code(std::errc::no_such_device).message());
  EXPECT_TRUE(g.buses[0]->closed());
}

TEST(RoleFailure, AGatewayStoppedOnPurposeReportsNoFailure) {
  asio::io_context io;
  GatewayUnderTest g(io, ScriptedBus::Receive::waits);
  g.gateway->start();
  io.poll();
  g.gateway->stop();
  io.run_for(std::chrono::milliseconds(200));
  EXPECT_TRUE(g.reports.empty());
  EXPECT_TRUE(g.gateway->failure().empty());
  EXPECT_TRUE(io.stopped());
}

TEST(RoleFailure, ASurfaceBusReaderThatThrowsStopsTheSurfaceAndSaysWhy) {
  for (auto receive : {ScriptedBus::Receive::throws, ScriptedBus::Receive::fails}) {
    asio::io_context io;
    auto bus = std::make_unique<ScriptedBus>(io.get_executor(), "surface-bus", receive);
    ScriptedBus* raw = bus.get();
    Surface surface(io.get_executor(), "s", std::move(bus), SurfacePolicy{{{"gw", {0, 1}, {}}}});
    std::vector<std::string> reports;
    surface.on_failure([&](const std::string& why) { reports.push_back(why); });
    surface.start();
    io.run_for(std::chrono::milliseconds(200));
    ASSERT_EQ(reports.size(), 1u);
    EXPECT_EQ(reports[0], "reader of bus surface-bus stopped: " +
                              (receive == ScriptedBus::Receive::throws
                                   ? std::string("scripted receive failure")
                                   : std::make_error_code(std::errc::no_such_device).message()));
    EXPECT_EQ(surface.failure(), reports[0]);
    EXPECT_TRUE(raw->closed());
    EXPECT_TRUE(io.stopped());  // the deadline driver ended too: the surface stopped in order
  }
}

TEST(RoleFailure, ASurfaceStoppedOnPurposeReportsNoFailure) {
  asio::io_context io;
  Surface surface(
      io.get_executor(), "s",
      std::make_unique<ScriptedBus>(io.get_executor(), "b", ScriptedBus::Receive::waits),
      SurfacePolicy{{{"gw", {0, 1}, {}}}});
  std::vector<std::string> reports;
  surface.on_failure([&](const std::string& why) { reports.push_back(why); });
  surface.start();
  io.poll();
  surface.stop();
  io.run_for(std::chrono::milliseconds(200));
  EXPECT_TRUE(reports.empty());
  EXPECT_TRUE(surface.failure().empty());
}

}  // namespace
}  // namespace canbridge::bridge
