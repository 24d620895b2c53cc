// One surface and several real gateways in process, over loopback TCP: each gateway is bound by
// the name in its hello, traffic is routed by module both ways, a gateway announcing a module
// another one serves is refused without disturbing the others, a restarted gateway comes back,
// reliable frames cross link cuts exactly once and in order, each sender's frames reach the far
// bus in the order it sent them, and the surface's statistics count the gateways' nodes.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/io_context.hpp>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;

using test::BusRecorder;
using test::drains_within;
using test::run_until;

// One gateway "process": its own module buses (a node endpoint on each, to write and to record),
// a Gateway and a TcpClient to the surface.
class GatewayRig {
 public:
  // `pairs`: a module's (local, surface) node ids when not the default mapping.
  GatewayRig(asio::io_context& io, const std::string& name, const std::vector<ModuleId>& ids,
             std::uint16_t port,
             const std::map<ModuleId, std::vector<std::pair<NodeId, NodeId>>>& pairs = {},
             std::chrono::milliseconds backoff_max = 50ms) {
    NodeMap map;
    std::vector<GatewayModule> modules;
    for (ModuleId id : ids) {
      media.push_back(
          std::make_unique<can::VirtualBus>(io.get_executor(), name + "-m" + std::to_string(id)));
      EXPECT_TRUE(map.add_module(id, pairs.contains(id) ? pairs.at(id) : NodeMap::default_pairs(id))
                      .empty());
      // A short lost time, so the node table's timer is seen working within the test.
      modules.push_back({id, media.back()->connect("gateway"), true, false, 150ms});
      nodes.push_back(std::make_unique<BusRecorder>(io, media.back()->connect("node")));
    }
    gateway =
        std::make_unique<Gateway>(io.get_executor(), name, std::move(map), std::move(modules));
    gateway->start();
    backbone::ClientOptions options;
    options.backoff_min = 10ms;  // reconnects (after cuts and refusals) within the test's time
    options.backoff_max = backoff_max;
    client = backbone::TcpClient::create(io.get_executor(), "127.0.0.1", port, options);
    client->start([this](auto link) {
      connects.push_back(std::chrono::steady_clock::now());
      gateway->attach(std::move(link));
    });
  }

  // The process "exits": its link closes, its buses stop.
  void stop() {
    client->stop();
    gateway->stop();
    for (auto& n : nodes) n->close();
  }
  bool stopped() const {
    return std::all_of(nodes.begin(), nodes.end(), [](const auto& n) { return n->done(); });
  }
  bool connected() const { return gateway->connected(); }
  BusRecorder& node(std::size_t module_index = 0) { return *nodes.at(module_index); }

  std::vector<std::unique_ptr<can::VirtualBus>> media;  // first: outlive the endpoints below
  std::vector<std::unique_ptr<BusRecorder>> nodes;
  std::unique_ptr<Gateway> gateway;
  std::shared_ptr<backbone::TcpClient> client;
  std::vector<std::chrono::steady_clock::time_point> connects;  // each TCP connect
};

// An SDO response (expedited upload) from local node `node` carrying `n`: a reliable frame whose
// number shows order and duplicates.
can::Frame sdo_response(std::uint8_t node, std::uint32_t n) {
  return can::Frame::standard(0x580 + node, {0x43, 0x00, 0x20, 0x00, static_cast<std::uint8_t>(n),
                                             static_cast<std::uint8_t>(n >> 8), 0, 0});
}
can::Frame emcy(std::uint8_t node, std::uint32_t n) {
  return can::Frame::standard(0x080 + node, {0x00, 0x10, 0x01, 0x00, static_cast<std::uint8_t>(n),
                                             static_cast<std::uint8_t>(n >> 8), 0, 0});
}
can::Frame sdo_request(std::uint8_t node, std::uint32_t n) {
  return can::Frame::standard(0x600 + node, {0x40, 0x00, 0x20, 0x00, static_cast<std::uint8_t>(n),
                                             static_cast<std::uint8_t>(n >> 8), 0, 0});
}

// True when the frames with `id` carry exactly the numbers 0..n-1, in order.
::testing::AssertionResult exactly_once_in_order(const BusRecorder& r, std::uint32_t id,
                                                 std::uint32_t n) {
  std::vector<std::uint32_t> got;
  for (const auto& f : r.frames) {
    if (f.id == id) got.push_back(f.data[4] | (std::uint32_t{f.data[5]} << 8));
  }
  if (got.size() != n) {
    return ::testing::AssertionFailure()
           << "0x" << std::hex << id << std::dec << ": " << got.size() << " frames, expected " << n;
  }
  for (std::uint32_t i = 0; i < n; ++i) {
    if (got[i] != i) {
      return ::testing::AssertionFailure()
             << "0x" << std::hex << id << std::dec << ": frame " << i << " carries " << got[i];
    }
  }
  return ::testing::AssertionSuccess();
}

// Default mapping: surface node = local + 32 x module. Local node 5 is surface node 37 on module 1
// (gateway A) and 69 on module 2 (gateway B).
constexpr std::uint8_t kLocal = 5;
constexpr std::uint32_t kSurfaceNodeA = 37;
constexpr std::uint32_t kSurfaceNodeB = 69;

class SurfaceGateways : public ::testing::Test {
 protected:
  SurfaceGateways() {
    surface.start();
    EXPECT_FALSE(server->start("127.0.0.1", 0, [this](auto link) { surface.attach(link); }));
  }
  void TearDown() override {
    for (auto& rig : rigs) rig->stop();
    server->stop();
    surface.stop();
    master.close();
    EXPECT_TRUE(run_until(io, [&] {
      return master.done() &&
             std::all_of(rigs.begin(), rigs.end(), [](const auto& r) { return r->stopped(); });
    }));
    // Nothing left pending: every coroutine saw its bus or link close.
    EXPECT_TRUE(drains_within(io, 2s));
  }

  GatewayRig& add_gateway(
      const std::string& name, const std::vector<ModuleId>& modules,
      const std::map<ModuleId, std::vector<std::pair<NodeId, NodeId>>>& pairs = {},
      std::chrono::milliseconds backoff_max = 50ms) {
    rigs.push_back(
        std::make_unique<GatewayRig>(io, name, modules, server->port(), pairs, backoff_max));
    return *rigs.back();
  }
  // Gateways A (module 1) and B (module 2), both up.
  void start_a_and_b() {
    a = &add_gateway("gw-a", {1});
    b = &add_gateway("gw-b", {2});
    ASSERT_TRUE(run_until(
        io, [&] { return surface.gateways_ready() == 2 && a->connected() && b->connected(); }));
  }

  asio::io_context io{1};
  can::VirtualBus medium{io.get_executor(), "surface-bus"};
  BusRecorder master{io, medium.connect("master")};  // the CANopen master on the surface bus
  // Plain loopback: A module 1, B module 2, C modules 3 and 5 (surface ids 97..127), D module 4.
  // The master's SDO time-out: 2 s, so a request in flight at a cut waits 1.6 s for its answer.
  Surface surface{
      io.get_executor(), "surface", medium.connect("surface"),
      SurfacePolicy{{{"gw-a", {1}, {}}, {"gw-b", {2}, {}}, {"gw-c", {3, 5}, {}}, {"gw-d", {4}, {}}},
                    false,
                    2000ms}};
  std::shared_ptr<backbone::TcpServer> server = backbone::TcpServer::create(io.get_executor());
  std::vector<std::unique_ptr<GatewayRig>> rigs;
  GatewayRig* a = nullptr;
  GatewayRig* b = nullptr;
};

TEST_F(SurfaceGateways, TwoGatewaysComeUpAndTrafficIsRoutedByModule) {
  start_a_and_b();
  EXPECT_EQ(surface.counters().session.links, 2u);

  // Module buses -> surface, with node ids translated per module.
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x180 + kLocal, {0xA1})));
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(b->node().send(can::Frame::standard(0x180 + kLocal, {0xB1})));
  ASSERT_TRUE(b->node().send(can::Frame::standard(0x700 + kLocal, {0x7F})));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= 4; }));
  EXPECT_EQ(master.frames.size(), 4u);
  EXPECT_TRUE(master.saw(can::Frame::standard(0x180 + kSurfaceNodeA, {0xA1})));
  EXPECT_TRUE(master.saw(can::Frame::standard(0x700 + kSurfaceNodeA, {0x05})));
  EXPECT_TRUE(master.saw(can::Frame::standard(0x180 + kSurfaceNodeB, {0xB1})));
  EXPECT_TRUE(master.saw(can::Frame::standard(0x700 + kSurfaceNodeB, {0x7F})));

  // Surface -> only the gateway claiming the node; SYNC, a broadcast, follows to both.
  const can::Frame sync = can::Frame::standard(0x080, {});
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeB, 1)));
  ASSERT_TRUE(master.send(sync));
  ASSERT_TRUE(run_until(io, [&] { return a->node().saw(sync) && b->node().saw(sync); }));
  // (The outbox may put the SYNC first within a batch: counts, not order.)
  EXPECT_EQ(b->node().count(0x600 + kLocal), 1u);
  EXPECT_TRUE(b->node().saw(sdo_request(kLocal, 1)));
  EXPECT_EQ(a->node().frames, std::vector{sync});
  EXPECT_EQ(a->gateway->counters().frames_received, 1u);  // the request never went to A
  EXPECT_EQ(a->gateway->counters().translation[static_cast<std::size_t>(DropReason::unknown_node)],
            0u);

  // NMT addressed to A's node: to A only, the node id in the payload translated too.
  ASSERT_TRUE(master.send(can::Frame::standard(0x000, {0x01, kSurfaceNodeA})));
  ASSERT_TRUE(master.send(sync));
  ASSERT_TRUE(
      run_until(io, [&] { return a->node().count(0x080) == 2 && b->node().count(0x080) == 2; }));
  EXPECT_EQ(a->node().frames.size(), 3u);
  EXPECT_TRUE(a->node().saw(can::Frame::standard(0x000, {0x01, kLocal})));
  EXPECT_EQ(b->node().frames.size(), 3u);  // the request and two SYNCs: no NMT
  // NMT to all: every module.
  ASSERT_TRUE(master.send(can::Frame::standard(0x000, {0x80, 0})));
  ASSERT_TRUE(
      run_until(io, [&] { return a->node().count(0x000) == 2 && b->node().count(0x000) == 1; }));
  EXPECT_EQ(surface.counters().dropped_unclaimed, 0u);
}

TEST_F(SurfaceGateways, FramesToANodeNoGatewayClaimsAreCountedAndGoNowhere) {
  start_a_and_b();
  const can::Frame sync = can::Frame::standard(0x080, {});
  ASSERT_TRUE(master.send(sdo_request(5, 1)));                         // node 5: nobody's
  ASSERT_TRUE(master.send(can::Frame::standard(0x000, {0x81, 120})));  // nobody's
  ASSERT_TRUE(master.send(sync));
  ASSERT_TRUE(run_until(io, [&] { return a->node().saw(sync) && b->node().saw(sync); }));
  EXPECT_EQ(surface.counters().dropped_unclaimed, 2u);
  EXPECT_EQ(a->gateway->counters().frames_received, 1u);
  EXPECT_EQ(b->gateway->counters().frames_received, 1u);
  EXPECT_THAT(surface.stats_line(), ::testing::HasSubstr("unclaimed 2"));
}

TEST_F(SurfaceGateways, AGatewayClaimingSurfaceIdsOfAnotherIsRefusedAndTheOthersKeepWorking) {
  start_a_and_b();
  // Module 5 maps its local node 1 onto surface 37, which is gateway A's module 1 node 5.
  GatewayRig& c = add_gateway("gw-c", {5}, {{5, {{1, kSurfaceNodeA}, {2, 100}}}});
  ASSERT_TRUE(run_until(io, [&] {
    return surface.counters().session.refusals_sent >= 1 &&
           c.gateway->counters().session.refusals_received >= 1;
  }));
  EXPECT_FALSE(c.connected());
  EXPECT_EQ(surface.gateways_ready(), 2u);
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 4)));
  ASSERT_TRUE(run_until(io, [&] { return !a->node().frames.empty(); }));
  EXPECT_EQ(a->node().frames, std::vector{sdo_request(kLocal, 4)});
  EXPECT_TRUE(c.node().frames.empty());
}

TEST_F(SurfaceGateways, AGatewayAnnouncingAServedModuleIsRefusedAndTheOthersKeepWorking) {
  start_a_and_b();
  GatewayRig& c = add_gateway("gw-c", {3, 1});  // module 1 is A's
  ASSERT_TRUE(run_until(io, [&] {
    return surface.counters().session.refusals_sent >= 2 &&
           c.gateway->counters().session.refusals_received >= 2;  // it keeps trying, and is refused
  }));
  EXPECT_FALSE(c.connected());
  EXPECT_EQ(surface.gateways_ready(), 2u);
  EXPECT_EQ(c.gateway->counters().session.links, 0u);

  // A and B work on while C keeps knocking.
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x180 + kLocal, {0xA2})));
  ASSERT_TRUE(b->node().send(can::Frame::standard(0x180 + kLocal, {0xB2})));
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 2)));
  ASSERT_TRUE(
      run_until(io, [&] { return master.frames.size() >= 2 && !a->node().frames.empty(); }));
  EXPECT_TRUE(master.saw(can::Frame::standard(0x180 + kSurfaceNodeA, {0xA2})));
  EXPECT_TRUE(master.saw(can::Frame::standard(0x180 + kSurfaceNodeB, {0xB2})));
  EXPECT_EQ(a->node().frames, std::vector{sdo_request(kLocal, 2)});
  // Module 3 of the refused gateway never reached the surface: its frames go nowhere.
  EXPECT_TRUE(c.node(1).frames.empty());
  // Neither A nor B lost its link over C.
  EXPECT_EQ(a->gateway->counters().session.links, 1u);
  EXPECT_EQ(b->gateway->counters().session.links, 1u);
  EXPECT_TRUE(a->connected());
  EXPECT_TRUE(b->connected());
  EXPECT_EQ(a->gateway->counters().session.refusals_received, 0u);
}

TEST_F(SurfaceGateways, ARestartedGatewayComesBackOnceTheOldLinkIsGone) {
  start_a_and_b();
  // A's new process starts while the surface still has the old one's link: refused.
  GatewayRig& again = add_gateway("gw-a", {1});
  ASSERT_TRUE(
      run_until(io, [&] { return again.gateway->counters().session.refusals_received >= 1; }));
  EXPECT_FALSE(again.connected());
  EXPECT_TRUE(a->connected());

  a->stop();  // the old process exits
  ASSERT_TRUE(run_until(io, [&] { return again.connected() && surface.gateways_ready() == 2; }));
  EXPECT_EQ(surface.counters().session.peer_restarts, 1u);

  ASSERT_TRUE(again.node().send(can::Frame::standard(0x180 + kLocal, {0xEE})));
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 3)));
  ASSERT_TRUE(
      run_until(io, [&] { return !master.frames.empty() && !again.node().frames.empty(); }));
  EXPECT_EQ(master.frames, std::vector{can::Frame::standard(0x180 + kSurfaceNodeA, {0xEE})});
  EXPECT_EQ(again.node().frames, std::vector{sdo_request(kLocal, 3)});
  EXPECT_TRUE(a->node().frames.empty());  // the old process is gone
  EXPECT_TRUE(b->connected());
}

TEST_F(SurfaceGateways, SdoValuesThatNameIdsAreSeenInSurfaceIdsBothWays) {
  start_a_and_b();
  // The master reads 1200h:01 (SDO server rx COB-ID) of surface node 37: the node answers with
  // its bus COB-ID 0x605, the master must see 0x625.
  ASSERT_TRUE(master.send(
      can::Frame::standard(0x600 + kSurfaceNodeA, {0x40, 0x00, 0x12, 0x01, 0, 0, 0, 0})));
  ASSERT_TRUE(run_until(io, [&] { return !a->node().frames.empty(); }));
  ASSERT_TRUE(a->node().send(
      can::Frame::standard(0x580 + kLocal, {0x43, 0x00, 0x12, 0x01, 0x05, 0x06, 0, 0})));
  const can::Frame seen =
      can::Frame::standard(0x580 + kSurfaceNodeA, {0x43, 0x00, 0x12, 0x01, 0x25, 0x06, 0, 0});
  ASSERT_TRUE(run_until(io, [&] { return master.saw(seen); })) << master.frames.size();

  // The master writes 1800h:01 (TPDO1 COB-ID) with its surface id 0x1A5, bit 31 set (disabled):
  // the node must get its own 0x185 with the flag kept.
  ASSERT_TRUE(master.send(can::Frame::standard(0x600 + kSurfaceNodeA,
                                               {0x23, 0x00, 0x18, 0x01, 0xA5, 0x01, 0x00, 0x80})));
  const can::Frame written =
      can::Frame::standard(0x600 + kLocal, {0x23, 0x00, 0x18, 0x01, 0x85, 0x01, 0x00, 0x80});
  ASSERT_TRUE(run_until(io, [&] { return a->node().saw(written); }));
  // Heartbeat consumer 1016h:01 naming node 69 (gateway B's): no counterpart on module 1's bus,
  // so forwarded unchanged and counted.
  ASSERT_TRUE(master.send(
      can::Frame::standard(0x600 + kSurfaceNodeA, {0x23, 0x16, 0x10, 0x01, 0xE8, 0x03, 69, 0x00})));
  ASSERT_TRUE(run_until(io, [&] { return a->gateway->counters().sdo_values_unmapped == 1; }));
  EXPECT_EQ(a->gateway->counters().sdo_values_rewritten, 2u);
}

TEST_F(SurfaceGateways, NodeTableEventsBootedAndLostReachTheSurface) {
  start_a_and_b();
  // A boot-up, one heartbeat, then silence: the gateway reports booted, then (150 ms after the
  // heartbeat, from which the node is watched) lost.
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x00})));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().node_events >= 1; }));
  const NodeRecord* record = a->gateway->node_table().node(0, kLocal);
  ASSERT_NE(record, nullptr);
  EXPECT_EQ(record->boot_count, 1u);
  const auto beat_at = std::chrono::steady_clock::now();
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x7F})));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().node_events >= 2; }));
  EXPECT_GE(std::chrono::steady_clock::now() - beat_at, 150ms);
  EXPECT_TRUE(a->gateway->node_table().node(0, kLocal)->lost);
  EXPECT_EQ(a->gateway->counters().node_events, 2u);
  EXPECT_EQ(surface.counters().node_events, 2u);
}

// The surface's statistics count every gateway's nodes from their events; the nodes of a gateway
// whose link is down count as lost, those of a restarted gateway are forgotten until the new
// process reports them. The nodes keep beating (each check sends a heartbeat), so none is lost
// by the gateways' 150 ms rule.
TEST_F(SurfaceGateways, SurfaceStatisticsCountTheGatewaysNodesByTheirEvents) {
  start_a_and_b();
  GatewayRig* gateway_a = a;
  std::optional<std::uint8_t> a_beats = 0x05;  // A's node's heartbeat state; nullopt: silent
  const auto nodes_are = [&](std::uint64_t op, std::uint64_t pre_op, std::uint64_t stopped,
                             std::uint64_t lost) {
    if (a_beats) {
      EXPECT_TRUE(gateway_a->node().send(can::Frame::standard(0x700 + kLocal, {*a_beats})));
    }
    EXPECT_TRUE(b->node().send(can::Frame::standard(0x700 + kLocal, {0x7F})));
    const NodeSummary n = surface.statistics().nodes;
    return n.operational == op && n.pre_operational == pre_op && n.stopped == stopped &&
           n.lost == lost && n.in_loader == 0;
  };
  EXPECT_EQ(surface.statistics().nodes.total(), 0u);
  ASSERT_TRUE(run_until(io, [&] { return nodes_are(1, 1, 0, 0); }))
      << surface.statistics().nodes.total();

  a->client->stop();  // A's link is lost and stays lost; its node still beats on its bus
  ASSERT_TRUE(run_until(io, [&] { return nodes_are(0, 1, 0, 1); }));
  EXPECT_FALSE(a->connected());

  a->stop();  // A's process exits; a new one takes its place
  a_beats.reset();
  ASSERT_TRUE(run_until(io, [&] { return a->stopped(); }));
  gateway_a = &add_gateway("gw-a", {1});
  ASSERT_TRUE(run_until(io, [&] {
    return surface.counters().session.peer_restarts == 1 && surface.gateways_ready() == 2;
  }));
  // Up again, but the old process's node is not the new one's: not counted until it is heard.
  EXPECT_TRUE(nodes_are(0, 1, 0, 0));
  a_beats = 0x04;
  ASSERT_TRUE(run_until(io, [&] { return nodes_are(0, 1, 1, 0); }));
}

TEST_F(SurfaceGateways, ReliableFramesCrossCutsExactlyOnceInOrder) {
  start_a_and_b();
  constexpr std::uint32_t kSdoA = 0x580 + kSurfaceNodeA;
  constexpr std::uint32_t kSdoB = 0x580 + kSurfaceNodeB;
  constexpr std::uint32_t kHeartbeatA = 0x700 + kSurfaceNodeA;

  // Every reliable payload A sent (first transmissions) was delivered by the surface exactly once.
  auto delivered_once = [&] {
    return surface.counters().session.reliable_delivered ==
           a->gateway->counters().session.reliable_sent +
               b->gateway->counters().session.reliable_sent;
  };

  // Cut 1, on the gateway side, at the moment the first responses reach the surface bus; the rest
  // of the burst is then in A's queue, in its resend buffer or on the wire.
  bool cut = false;
  master.on_frames = [&] {
    if (cut || master.count(kSdoA) == 0) return;
    cut = true;
    if (auto link = a->client->link()) link->close();
  };
  for (std::uint32_t n = 0; n < 300; ++n) ASSERT_TRUE(a->node().send(sdo_response(kLocal, n)));
  ASSERT_TRUE(run_until(io, [&] { return cut && !a->connected(); }));
  // Written while the link is down: queued by the gateway until the next link.
  for (std::uint32_t n = 300; n < 600; ++n) ASSERT_TRUE(a->node().send(sdo_response(kLocal, n)));
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] {
    return a->connected() && master.count(kSdoA) >= 600 && master.count(kHeartbeatA) >= 1 &&
           a->gateway->stream().sender().unacked_count() == 0;  // no retransmission can follow
  }));
  EXPECT_TRUE(exactly_once_in_order(master, kSdoA, 600));
  EXPECT_EQ(master.count(kHeartbeatA), 1u);
  EXPECT_TRUE(delivered_once());

  // Cut 2, on the surface side, every link at once, while a long burst from A is arriving: what
  // A sent and the surface had not processed is lost with the link and must be resent.
  cut = false;
  std::uint64_t sent_at_cut = 0;
  std::uint64_t delivered_at_cut = 0;
  std::uint64_t resent_before = a->gateway->counters().session.reliable_resent;
  master.on_frames = [&] {
    if (cut || master.count(kSdoA) <= 600) return;
    cut = true;
    sent_at_cut = a->gateway->counters().session.reliable_sent;
    delivered_at_cut = surface.counters().session.reliable_delivered;
    for (const auto& link : server->links()) link->close();
  };
  for (std::uint32_t n = 600; n < 3000; ++n) ASSERT_TRUE(a->node().send(sdo_response(kLocal, n)));
  ASSERT_TRUE(run_until(io, [&] { return cut && !a->connected() && !b->connected(); }));
  master.on_frames = nullptr;
  // While both links are down, both directions queue (SDO requests would be aborted: the master
  // must not wait on a dead link; EMCY from the surface bus is reliable and queues).
  for (std::uint32_t n = 0; n < 300; ++n) ASSERT_TRUE(b->node().send(sdo_response(kLocal, n)));
  for (std::uint32_t n = 0; n < 100; ++n) ASSERT_TRUE(master.send(emcy(kSurfaceNodeB, n)));
  ASSERT_TRUE(run_until(io, [&] {
    return a->connected() && b->connected() && master.count(kSdoA) >= 3000 &&
           master.count(kSdoB) >= 300 && b->node().frames.size() >= 100 &&
           a->gateway->stream().sender().unacked_count() == 0 &&
           b->gateway->stream().sender().unacked_count() == 0;
  }));
  EXPECT_TRUE(exactly_once_in_order(master, kSdoA, 3000));
  EXPECT_TRUE(exactly_once_in_order(master, kSdoB, 300));
  EXPECT_TRUE(exactly_once_in_order(b->node(), 0x080 + kLocal, 100));
  EXPECT_TRUE(a->node().frames.empty());  // frames for B's node never reach A's module
  EXPECT_TRUE(delivered_once());
  const std::uint64_t resent = a->gateway->counters().session.reliable_resent - resent_before;
  // The surface processed nothing on a link after closing it: anything sent beyond what it had
  // delivered by then was lost with the link, and only a resend can have brought it.
  if (sent_at_cut > delivered_at_cut) {
    EXPECT_GT(resent, 0u);
  }
  std::printf("cut 2: A had sent %llu payloads, the surface delivered %llu; %llu resent\n",
              static_cast<unsigned long long>(sent_at_cut),
              static_cast<unsigned long long>(delivered_at_cut),
              static_cast<unsigned long long>(resent));

  // The same processes resumed their streams; nobody restarted or refused anything.
  const SurfaceCounters s = surface.counters();
  EXPECT_EQ(s.session.peer_restarts, 0u);
  EXPECT_EQ(s.session.refusals_sent, 0u);
  EXPECT_EQ(s.outbox.reliable_refused, 0u);
  EXPECT_EQ(a->gateway->counters().session.links, 3u);
  EXPECT_EQ(b->gateway->counters().session.links, 2u);
  EXPECT_EQ(a->gateway->counters().outbox.reliable_refused, 0u);
}

}  // namespace
}  // namespace canbridge::bridge

namespace canbridge::bridge {
namespace {

// Abort 0x05040000 from surface node `node` for object 2000h:00, as the surface must answer.
can::Frame link_down_abort(std::uint32_t node) {
  return can::Frame::standard(0x580 + node, {0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x04, 0x05});
}

TEST_F(SurfaceGateways, SdoToANodeBehindALostLinkIsAbortedBeforeTheMastersTimeOut) {
  start_a_and_b();
  // The surface learns who owns which node from the gateways' traffic (here: heartbeats).
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(b->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= 2; }));
  // A request in flight (the node has not answered) when A's link drops: its answer may still
  // come with the next link, until 1.6 s after the request; then the abort, before the
  // master's own time-out (2 s).
  const auto sent_at = std::chrono::steady_clock::now();
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 1)));
  ASSERT_TRUE(run_until(io, [&] { return a->node().count(0x600 + kLocal) == 1; }));
  a->client->stop();  // the link is lost and stays lost
  ASSERT_TRUE(run_until(
      io, [&] { return master.saw(link_down_abort(kSurfaceNodeA)); }, 5s));
  const auto aborted_after = std::chrono::steady_clock::now() - sent_at;
  EXPECT_GE(aborted_after, 1600ms);
  EXPECT_LT(aborted_after, 2000ms);
  EXPECT_FALSE(a->connected());
  // A new request to A's node: answered by the surface, never queued for the dead link.
  const std::size_t aborts_before = master.count(0x580 + kSurfaceNodeA);
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 2)));
  ASSERT_TRUE(
      run_until(io, [&] { return master.count(0x580 + kSurfaceNodeA) == aborts_before + 1; }));
  EXPECT_EQ(surface.counters().sdo_guard.aborted(), 2u);
  // B's node is untouched: its request goes through, its answer comes back.
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeB, 3)));
  ASSERT_TRUE(run_until(io, [&] { return b->node().count(0x600 + kLocal) == 1; }));
  ASSERT_TRUE(b->node().send(sdo_response(kLocal, 3)));
  ASSERT_TRUE(run_until(io, [&] { return master.count(0x580 + kSurfaceNodeB) == 1; }));
  EXPECT_EQ(surface.counters().sdo_guard.aborted(), 2u);
}

// Issue 27: the request reached the node before the cut and was executed; the node's answer
// waits in the gateway's stream and crosses on the next link, in time: the master gets the
// answer, not an abort that would claim a failure.
TEST_F(SurfaceGateways, TheAnswerToARequestInFlightAtACutComesWithTheNextLink) {
  start_a_and_b();
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= 1; }));
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 1)));
  ASSERT_TRUE(run_until(io, [&] { return a->node().count(0x600 + kLocal) == 1; }));
  if (auto link = a->client->link()) link->close();  // the gateway reconnects within 50 ms
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));
  ASSERT_TRUE(a->node().send(sdo_response(kLocal, 1)));  // executed; answered while cut
  ASSERT_TRUE(run_until(io, [&] { return master.count(0x580 + kSurfaceNodeA) == 1; }));
  EXPECT_TRUE(master.saw(sdo_response(kSurfaceNodeA, 1)));
  EXPECT_EQ(surface.counters().sdo_guard.answers_recovered, 1u);
  EXPECT_EQ(surface.counters().sdo_guard.aborted(), 0u);
  // Nothing else follows: no abort when the wait would have ended (1.6 s after the request).
  EXPECT_FALSE(run_until(
      io, [&] { return master.count(0x580 + kSurfaceNodeA) > 1; }, 1700ms));
}

// Issue 27: a request whose answer never comes on a live link (lost on a bad line and given up
// by the gateway's stream, or a node that never answers) gets the abort before its master's own
// time-out, as one in flight at a cut does; the link stays up and the late answer is dropped.
TEST_F(SurfaceGateways, ARequestUnansweredOnALiveLinkIsAbortedBeforeTheMastersTimeOut) {
  start_a_and_b();
  ASSERT_TRUE(a->node().send(can::Frame::standard(0x700 + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= 1; }));
  const auto sent_at = std::chrono::steady_clock::now();
  ASSERT_TRUE(master.send(sdo_request(kSurfaceNodeA, 1)));
  ASSERT_TRUE(run_until(io, [&] { return a->node().count(0x600 + kLocal) == 1; }));
  ASSERT_TRUE(run_until(
      io, [&] { return master.saw(link_down_abort(kSurfaceNodeA)); }, 5s));
  const auto aborted_after = std::chrono::steady_clock::now() - sent_at;
  EXPECT_GE(aborted_after, 1600ms);
  EXPECT_LT(aborted_after, 2000ms);
  EXPECT_TRUE(a->connected());
  EXPECT_EQ(surface.counters().sdo_guard.aborted_overdue, 1u);
  EXPECT_EQ(surface.counters().sdo_guard.aborted(), 0u);  // no link went down
  // The node answers after all: too late, never passed to the master.
  ASSERT_TRUE(a->node().send(sdo_response(kLocal, 1)));
  ASSERT_TRUE(
      run_until(io, [&] { return surface.counters().sdo_guard.late_responses_dropped == 1; }));
  EXPECT_EQ(master.count(0x580 + kSurfaceNodeA), 1u);
}

}  // namespace
}  // namespace canbridge::bridge

namespace canbridge::bridge {
namespace {

TEST_F(SurfaceGateways, FramesTheBridgeWroteAreNeverForwardedAgainWhenABusEchoesThem) {
  start_a_and_b();
  // Module side: the surface's SDO request reaches A's bus as 0x605; something on that bus (a
  // second bridge, a gateway daemon) sends it again. The gateway must not carry it back.
  const can::Frame request = sdo_request(kSurfaceNodeA, 7);
  ASSERT_TRUE(master.send(request));
  ASSERT_TRUE(run_until(io, [&] { return a->node().count(0x600 + kLocal) == 1; }));
  const can::Frame at_module = a->node().frames.back();
  ASSERT_TRUE(a->node().send(at_module));  // the echo
  const can::Frame marker = can::Frame::standard(0x700 + kLocal, {0x05});
  ASSERT_TRUE(a->node().send(marker));
  ASSERT_TRUE(run_until(
      io, [&] { return master.saw(can::Frame::standard(0x700 + kSurfaceNodeA, {0x05})); }));
  EXPECT_EQ(master.count(0x600 + kSurfaceNodeA), 0u);  // its own request never came back
  EXPECT_EQ(a->gateway->counters().echoes_dropped, 1u);

  // Surface side: the heartbeat the surface wrote, sent again on the surface bus, does not go
  // back to the module as a frame from the surface.
  const std::size_t at_node_before = a->node().frames.size();
  ASSERT_TRUE(master.send(can::Frame::standard(0x700 + kSurfaceNodeA, {0x05})));  // the echo
  const can::Frame surface_marker = sdo_request(kSurfaceNodeA, 8);
  ASSERT_TRUE(master.send(surface_marker));
  ASSERT_TRUE(run_until(io, [&] { return a->node().count(0x600 + kLocal) == 2; }));
  EXPECT_EQ(a->node().frames.size(), at_node_before + 1);  // only the marker arrived
  EXPECT_EQ(surface.counters().echoes_dropped, 1u);
}

TEST_F(SurfaceGateways, EachSendersFramesReachTheFarBusInItsOrder) {
  start_a_and_b();
  // Node 5 boots and reports an EMCY right after it; node 3's EMCY and SDO response interleave.
  // Written at once, they reach the gateway in one bus batch and cross in one backbone batch.
  constexpr std::uint8_t kOther = 3;  // surface node 35 on module 1
  const std::vector<can::Frame> module_frames = {
      can::Frame::standard(0x700 + kLocal, {0x00}),
      can::Frame::standard(0x080 + kOther, {0x00, 0x10, 0x01}),
      can::Frame::standard(0x080 + kLocal, {0x00, 0x50, 0x01}),
      sdo_response(kOther, 7),
  };
  for (const can::Frame& f : module_frames) ASSERT_TRUE(a->node().send(f));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= 4; }));
  // Node 35 may go first (its EMCY wins arbitration against a boot-up); node 37's EMCY must not
  // overtake node 37's boot-up, as it did when the outbox ordered by COB-ID alone.
  const std::uint32_t other = kOther + 32;
  EXPECT_EQ(master.frames,
            (std::vector{can::Frame::standard(0x080 + other, {0x00, 0x10, 0x01}),
                         sdo_response(static_cast<std::uint8_t>(other), 7),
                         can::Frame::standard(0x700 + kSurfaceNodeA, {0x00}),
                         can::Frame::standard(0x080 + kSurfaceNodeA, {0x00, 0x50, 0x01})}));

  // The master writes node 37's heartbeat period and then starts it: the NMT, the bus's most
  // urgent identifier, still reaches the module bus after the request sent ahead of it.
  const can::Frame request =
      can::Frame::standard(0x600 + kSurfaceNodeA, {0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0x00, 0x00});
  ASSERT_TRUE(master.send(request));
  ASSERT_TRUE(master.send(can::Frame::standard(0x000, {0x01, kSurfaceNodeA})));
  ASSERT_TRUE(run_until(io, [&] { return a->node().frames.size() >= 2; }));
  EXPECT_EQ(a->node().frames,
            (std::vector{can::Frame::standard(0x600 + kLocal,
                                              {0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0x00, 0x00}),
                         can::Frame::standard(0x000, {0x01, kLocal})}));
}

}  // namespace
}  // namespace canbridge::bridge

namespace canbridge::bridge {
namespace {

// Nodes with their heartbeat off have never been seen by the surface: the gateways' claims still
// make every request to them end in an answer or an abort, never in silence.
TEST_F(SurfaceGateways, NoSdoRequestToANeverSeenNodeVanishesWhenItsLinkIsCut) {
  start_a_and_b();
  constexpr std::uint32_t kNodes = 8;
  // A: delivered to the module bus (the node stays silent), then the link is cut.
  for (std::uint32_t i = 0; i < kNodes; ++i) ASSERT_TRUE(master.send(sdo_request(33 + i, i)));
  ASSERT_TRUE(run_until(io, [&] { return a->node().frames.size() == kNodes; }));
  a->client->stop();
  // B: cut in the same turn as the requests are sent: queued, in flight or after the cut.
  for (std::uint32_t i = 0; i < kNodes; ++i) ASSERT_TRUE(master.send(sdo_request(65 + i, i)));
  b->client->stop();
  auto aborted = [&](std::uint32_t node) {
    return master.count(0x580 + node) == 1 && master.saw(link_down_abort(node));
  };
  ASSERT_TRUE(run_until(io, [&] {
    for (std::uint32_t i = 0; i < kNodes; ++i) {
      if (!aborted(33 + i) || !aborted(65 + i)) return false;
    }
    return true;
  })) << surface.stats_line();
  EXPECT_EQ(surface.counters().sdo_guard.aborted(), 2 * kNodes);
  for (std::uint32_t i = 0; i < kNodes; ++i) {
    EXPECT_EQ(master.count(0x580 + 33 + i), 1u);
    EXPECT_EQ(master.count(0x580 + 65 + i), 1u);
  }
}

// A refused gateway waits twice as long before each new attempt, up to its maximum, instead of
// knocking ten times a second forever.
TEST_F(SurfaceGateways, ARefusedGatewayBacksOffExponentiallyToItsMaximum) {
  start_a_and_b();
  // Error lines, to see each side report the refusal once, not once per attempt.
  std::ostringstream errors;
  auto sink = std::make_shared<spdlog::sinks::ostream_sink_st>(errors);
  sink->set_level(spdlog::level::err);
  spdlog::default_logger()->sinks().push_back(sink);
  GatewayRig& c = add_gateway("gw-c", {1}, {}, 80ms);  // module 1 is A's; waits 10 ms .. 80 ms
  // A second refused gateway knocking at the same time: each keeps its own "once".
  GatewayRig& d = add_gateway("gw-d", {2}, {}, 80ms);  // module 2 is B's
  ASSERT_TRUE(run_until(io, [&] { return c.connects.size() >= 6 && d.connects.size() >= 6; }));
  const std::vector<std::chrono::milliseconds> schedule{10ms, 20ms, 40ms, 80ms, 80ms};
  for (std::size_t i = 0; i < schedule.size(); ++i) {
    EXPECT_GE(c.connects[i + 1] - c.connects[i], schedule[i]) << "attempt " << i + 2;
  }
  EXPECT_FALSE(c.connected());
  EXPECT_EQ(c.gateway->counters().session.links, 0u);
  EXPECT_TRUE(a->connected());
  EXPECT_GE(surface.counters().session.refusals_sent, 10u);
  spdlog::default_logger()->sinks().pop_back();
  auto lines_with = [text = errors.str()](const std::string& what) {
    std::size_t n = 0;
    for (auto at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
    return n;
  };
  // Over plain TCP neither proved who it is: both were told only "refused" (the surface's own
  // log has the details, at warn level), one line on the surface for the same text.
  EXPECT_EQ(lines_with("backbone: refusing"), 1u) << errors.str();
  EXPECT_EQ(lines_with("refused this gateway"), 2u) << errors.str();
  EXPECT_EQ(errors.str().find("module 1"), std::string::npos) << errors.str();
}

}  // namespace
}  // namespace canbridge::bridge
