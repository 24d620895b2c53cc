// A real Gateway and real Surfaces linked in memory: a surface process the gateway has not
// reported to (its first, a restarted one) learns every node of the gateway's node table in its
// present state, lost ones lost, without any node changing, even past the bound on queued node
// events; a plain reconnect to the same surface process sends nothing again.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
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
using can::Frame;
using test::BusRecorder;
using test::run_until;

// Module 1: three nodes that keep their states; module 2: one node that goes silent and is lost.
constexpr ModuleId kSteady = 1, kLossy = 2;

BackboneTuning quick_tuning() {
  BackboneTuning t;
  t.session.keepalive_interval = 20ms;
  t.session.dead_after = 300ms;
  t.session.retransmit_timeout = 100ms;
  // One queued payload: a snapshot (one payload per module) is more than the bound.
  t.outbox.max_node_event_payloads = 1;
  return t;
}

Frame heartbeat(canopen::NodeId node, std::uint8_t state) {
  return Frame::standard(0x700u + node, {state});
}

bool same(const NodeSummary& a, const NodeSummary& b) {
  return a.operational == b.operational && a.pre_operational == b.pre_operational &&
         a.stopped == b.stopped && a.in_loader == b.in_loader && a.lost == b.lost;
}

std::string text(const NodeSummary& s) {
  return std::to_string(s.operational) + " op, " + std::to_string(s.pre_operational) + " pre-op, " +
         std::to_string(s.stopped) + " stopped, " + std::to_string(s.in_loader) + " loader, " +
         std::to_string(s.lost) + " lost";
}

// Operational, pre-operational and stopped on module 1, lost on module 2.
const NodeSummary kAll{1, 1, 1, 0, 1};

class NodeSnapshot : public ::testing::Test {
 protected:
  void SetUp() override {
    NodeMap map;
    ASSERT_TRUE(map.add_module(kSteady, {{1, 3}, {2, 4}, {3, 5}}).empty());
    ASSERT_TRUE(map.add_module(kLossy, {{1, 6}}).empty());
    std::vector<GatewayModule> modules;
    GatewayModule steady;
    steady.id = kSteady;
    steady.bus = steady_bus.connect("gateway");
    steady.heartbeat_lost_after = std::chrono::hours(1);  // never lost within a test
    modules.push_back(std::move(steady));
    GatewayModule lossy;
    lossy.id = kLossy;
    lossy.bus = lossy_bus.connect("gateway");
    lossy.heartbeat_lost_after = 100ms;
    modules.push_back(std::move(lossy));
    gateway = std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules),
                                        quick_tuning());
    gateway->start();
  }

  void TearDown() override {
    gateway->stop();
    for (auto& s : surfaces) s->stop();
    steady_node.close();
    lossy_node.close();
    EXPECT_TRUE(run_until(io, [&] { return steady_node.done() && lossy_node.done(); }));
  }

  // A new surface process, started and linked to the gateway; true once the link is ready.
  bool link_new_surface() {
    surfaces.push_back(std::make_unique<Surface>(
        io.get_executor(), "surface",
        surface_bus.connect("surface-" + std::to_string(surfaces.size())),
        SurfacePolicy{{{"gw", {kSteady, kLossy}, {3, 4, 5, 6}}}, false}, quick_tuning()));
    surfaces.back()->start();
    return relink();
  }

  // A new link between the gateway and the newest surface.
  bool relink() {
    link = link_in_memory(io, surface(), *gateway);
    return run_until(io, [&] { return surface().gateways_ready() == 1 && gateway->connected(); });
  }

  bool cut() {
    link.b->close();
    return run_until(io, [&] { return !gateway->connected() && surface().gateways_ready() == 0; });
  }

  Surface& surface() { return *surfaces.back(); }
  NodeSummary nodes() { return surface().statistics().nodes; }

  // Each node heard once, the next only when the gateway's table counts the last one: the
  // events then cross one payload at a time (the bound is one).
  void hear_every_node() {
    const auto heard = [&](std::size_t n) { return gateway->node_table().counts().total() == n; };
    ASSERT_TRUE(steady_node.send(heartbeat(1, 0x05)));
    ASSERT_TRUE(run_until(io, [&] { return heard(1); }));
    ASSERT_TRUE(steady_node.send(heartbeat(2, 0x7F)));
    ASSERT_TRUE(run_until(io, [&] { return heard(2); }));
    ASSERT_TRUE(steady_node.send(heartbeat(3, 0x04)));
    ASSERT_TRUE(run_until(io, [&] { return heard(3); }));
    ASSERT_TRUE(lossy_node.send(heartbeat(1, 0x05)));
    ASSERT_TRUE(run_until(io, [&] { return gateway->node_table().counts().lost == 1; }));
  }

  boost::asio::io_context io{1};
  can::VirtualBus steady_bus{io.get_executor(), "steady"};
  can::VirtualBus lossy_bus{io.get_executor(), "lossy"};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder steady_node{io, steady_bus.connect("node")};
  BusRecorder lossy_node{io, lossy_bus.connect("node")};
  std::unique_ptr<Gateway> gateway;
  // Every surface process so far, the newest last (the stopped ones outlive the test's loop).
  std::vector<std::unique_ptr<Surface>> surfaces;
  backbone::MemoryLinkPair link;
};

TEST_F(NodeSnapshot, ARestartedSurfaceLearnsEveryNodeWithoutAnyNodeChanging) {
  ASSERT_TRUE(link_new_surface());
  hear_every_node();
  ASSERT_TRUE(run_until(io, [&] { return same(nodes(), kAll); })) << text(nodes());

  // The surface restarts: a new process behind a new link. No node says anything meanwhile.
  ASSERT_TRUE(cut());
  surface().stop();
  ASSERT_TRUE(link_new_surface());
  ASSERT_TRUE(run_until(io, [&] { return same(nodes(), kAll); }))
      << text(nodes()) << "; " << gateway->stats_line();
  // A DISCOVERED each, a LOST for the lost one: nothing more, nothing dropped.
  EXPECT_FALSE(run_until(
      io, [&] { return surface().counters().node_events > 5; }, 200ms));
  EXPECT_EQ(surface().counters().node_events, 5u);
  EXPECT_EQ(gateway->counters().node_events_dropped, 0u);
  EXPECT_EQ(gateway->counters().session.peer_restarts, 1u);

  // Later events follow the snapshot: the surface ends in the node's new state.
  ASSERT_TRUE(steady_node.send(heartbeat(1, 0x7F)));
  ASSERT_TRUE(run_until(io, [&] {
    return same(nodes(), NodeSummary{0, 2, 1, 0, 1});
  })) << text(nodes());
}

TEST_F(NodeSnapshot, TheFirstSurfaceLearnsNodesWhoseEventsTheBoundDropped) {
  // Heard while no surface was ever linked: with a bound of one payload, three events are gone.
  hear_every_node();
  EXPECT_GT(gateway->counters().node_events_dropped, 0u);
  ASSERT_TRUE(link_new_surface());
  ASSERT_TRUE(run_until(io, [&] { return same(nodes(), kAll); })) << text(nodes());
}

TEST_F(NodeSnapshot, AReconnectToTheSameSurfaceSendsNothingAgain) {
  ASSERT_TRUE(link_new_surface());
  hear_every_node();
  ASSERT_TRUE(run_until(io, [&] { return same(nodes(), kAll); })) << text(nodes());
  const std::uint64_t events = surface().counters().node_events;
  EXPECT_EQ(events, 5u);  // DISCOVERED x 4, LOST

  ASSERT_TRUE(cut());
  ASSERT_TRUE(relink());
  EXPECT_FALSE(run_until(
      io, [&] { return surface().counters().node_events != events; }, 300ms))
      << surface().counters().node_events << " node events";
  EXPECT_TRUE(same(nodes(), kAll)) << text(nodes());
  EXPECT_EQ(gateway->counters().session.links, 2u);
  EXPECT_EQ(gateway->counters().session.peer_restarts, 0u);
}

}  // namespace
}  // namespace canbridge::bridge
