// A gateway and a surface in process (virtual buses, TCP loopback) and a scripted node on the
// module bus (issue 14): a node renamed by the fpga node-id command to a free surface id moves in
// the gateway's live map, and the producer time written to a node's 1017h, by a master on either
// bus, reaches the gateway's node table.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
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
using can::Frame;
using test::BusRecorder;
using test::run_until;

constexpr ModuleId kModule = 1;
constexpr canopen::NodeId kLocal = 1, kSurface = 3, kFree = 9;

class GatewayNodes : public ::testing::Test {
 protected:
  void SetUp() override {
    NodeMap map;
    ASSERT_TRUE(map.add_module(kModule, {{kLocal, kSurface}, {2, 4}}).empty());
    std::vector<GatewayModule> modules;
    GatewayModule m;
    m.id = kModule;
    m.bus = module_bus.connect("gateway");
    modules.push_back(std::move(m));
    gateway =
        std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules));
    // The node: an fpga node-id command for itself resets it under the commanded id; every SDO
    // download is confirmed.
    node.on_frames = [this] {
      for (; node_seen < node.frames.size(); ++node_seen) {
        const Frame f = node.frames[node_seen];
        if (f.id == 0 && f.len == 3 && f.data[0] == 0xE0 && f.data[1] == kLocal) {
          node.send(Frame::standard(0x700u + f.data[2], {0x00}));
        } else if (f.id == 0x600u + kLocal && f.len == 8 && (f.data[0] >> 5) == 1) {
          node.send(Frame::standard(0x580u + kLocal,
                                    {0x60, f.data[1], f.data[2], f.data[3], 0, 0, 0, 0}));
        }
      }
    };
    ASSERT_TRUE(start_linked_over_loopback(io, surface, *gateway, server, client));
    ASSERT_TRUE(node.send(Frame::standard(0x700u + kLocal, {0x05})));  // the table knows it
    ASSERT_TRUE(run_until(io, [&] { return gateway->node_table().node(0, kLocal) != nullptr; }));
  }

  void TearDown() override {
    client->stop();
    gateway->stop();
    server->stop();
    surface.stop();
    master.close();
    node.close();
    local_master.close();
    EXPECT_TRUE(run_until(io, [&] { return master.done() && node.done() && local_master.done(); }));
  }

  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module-bus"};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  BusRecorder node{io, module_bus.connect("node")};
  BusRecorder local_master{io, module_bus.connect("local-master")};
  std::size_t node_seen = 0;
  // Surface ids 3 and 4, and 9, the free id a node is renamed to.
  Surface surface{io.get_executor(), "surface", surface_bus.connect("surface"),
                  SurfacePolicy{{{"gw", {kModule}, {kSurface, 4, kFree}}}, false}};
  std::shared_ptr<backbone::TcpServer> server = backbone::TcpServer::create(io.get_executor());
  std::unique_ptr<Gateway> gateway;
  std::shared_ptr<backbone::TcpClient> client;
};

TEST_F(GatewayNodes, ANodeRenamedToAFreeSurfaceIdMovesInTheLiveMap) {
  ASSERT_TRUE(master.send(Frame::standard(0x000, {0xE0, kSurface, kFree})));
  // The node reset under its own id; its boot-up reaches the master under the new surface id.
  ASSERT_TRUE(run_until(io, [&] { return master.saw(Frame::standard(0x700u + kFree, {0x00})); }))
      << gateway->stats_line();
  EXPECT_TRUE(node.saw(Frame::standard(0x000, {0xE0, kLocal, kLocal})));
  EXPECT_EQ(gateway->counters().nodes_moved, 1u);
  // SDO on the new id reaches the node; its answer comes back under the new id.
  ASSERT_TRUE(master.send(Frame::standard(0x600u + kFree, {0x23, 0x00, 0x20, 0x00, 1, 2, 3, 4})));
  ASSERT_TRUE(run_until(io, [&] { return master.count(0x580u + kFree) == 1; }));
  EXPECT_EQ(node.count(0x600u + kLocal), 1u);
  // The old id is free: the gateway's new claims (sent with the rename's node events) no longer
  // hold it, so the surface forwards nothing under it.
  const auto unclaimed = surface.counters().dropped_unclaimed;
  ASSERT_TRUE(master.send(Frame::standard(0x600u + kSurface, {0x40, 0x00, 0x10, 0x00})));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().dropped_unclaimed == unclaimed + 1; }));
  EXPECT_EQ(node.count(0x600u + kLocal), 1u);
  // An id the profile does not allow is refused: counted, the node never sees a command, and the
  // surface hears of it as a RENAME_UNCONFIRMED event.
  const auto surface_events = surface.counters().node_events;
  ASSERT_TRUE(master.send(Frame::standard(0x000, {0xE0, kFree, 0x80})));
  ASSERT_TRUE(run_until(io, [&] {
    return gateway->counters().translation[static_cast<std::size_t>(DropReason::rename_refused)] ==
           1;
  }));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().node_events == surface_events + 1; }));
  EXPECT_EQ(node.count(0x000), 1u);
  EXPECT_EQ(gateway->counters().nodes_moved, 1u);
}

TEST_F(GatewayNodes, TheProducerTimeWrittenTo1017hReachesTheNodeTable) {
  // From the surface master (value 200 ms)...
  ASSERT_TRUE(
      master.send(Frame::standard(0x600u + kSurface, {0x2B, 0x17, 0x10, 0x00, 200, 0, 0, 0})));
  ASSERT_TRUE(run_until(
      io, [&] { return gateway->node_table().node(0, kLocal)->heartbeat_time == 200ms; }));
  EXPECT_EQ(gateway->node_table().lost_after(0, kLocal), 600ms);
  // ... and from a master on the module bus (300 ms).
  ASSERT_TRUE(
      local_master.send(Frame::standard(0x600u + kLocal, {0x2B, 0x17, 0x10, 0x00, 44, 1, 0, 0})));
  ASSERT_TRUE(run_until(
      io, [&] { return gateway->node_table().node(0, kLocal)->heartbeat_time == 300ms; }));
  // Another object's write changes nothing.
  ASSERT_TRUE(
      master.send(Frame::standard(0x600u + kSurface, {0x2B, 0x00, 0x20, 0x00, 50, 0, 0, 0})));
  ASSERT_TRUE(run_until(io, [&] { return master.count(0x580u + kSurface) == 3; }));
  EXPECT_EQ(gateway->node_table().node(0, kLocal)->heartbeat_time, 300ms);
}

}  // namespace
}  // namespace canbridge::bridge
