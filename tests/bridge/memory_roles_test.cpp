// A real Gateway and a real Surface on virtual CAN buses, linked by an in-memory pair instead of
// TCP: frames cross translated both ways, a cut link and a new pair resume with every reliable
// frame exactly once, and the surface, facing scripted gateways, refuses one claiming the real
// gateway's node and a stranger (telling each only "refused"), routes to one whose claims are its
// own, and keeps a bound gateway's frames for nodes not its own off the surface bus.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "bridge/gateway_claims.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/backbone/envelopes.hpp"
#include "tests/backbone/scripted_peer.hpp"
#include "tests/bridge/loopback_roles.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using backbone::testing::hello;
using backbone::testing::hello_from;
using backbone::testing::PeerIdentity;
using backbone::testing::PeerScript;
using backbone::testing::ScriptedPeer;
using can::Frame;
using test::BusRecorder;
using test::run_until;

constexpr ModuleId kModule = 1;
constexpr canopen::NodeId kLocal = 2, kSurface = 5;
constexpr canopen::NodeId kTheirs = 20;  // "other-gw"'s one node

BackboneTuning quick_tuning() {
  BackboneTuning t;
  t.session.keepalive_interval = 20ms;
  t.session.dead_after = 300ms;
  t.session.retransmit_timeout = 100ms;
  return t;
}

// An EMCY (reliable) of `node` carrying a sequence number.
Frame emcy(canopen::NodeId node, std::uint32_t seq) {
  return Frame::standard(0x080u + node, {0x00, 0x10, 0x01, static_cast<std::uint8_t>(seq),
                                         static_cast<std::uint8_t>(seq >> 8)});
}

// A serialized Payload carrying `frames` of `module`, as a gateway sends them.
std::string frames_payload(ModuleId module, const std::vector<Frame>& frames) {
  v1::Payload p;
  FrameBatchBuilder builder;
  builder.start(*p.mutable_frames(), module);
  for (const Frame& f : frames) builder.append(*p.mutable_frames(), f);
  return p.SerializeAsString();
}

// A gateway of its own (not the real one) serving `module` with one node: its hello's identity.
PeerIdentity scripted_gateway(std::string name, ModuleId module, canopen::NodeId local,
                              canopen::NodeId surface_id) {
  NodeMap map;
  EXPECT_TRUE(map.add_module(module, {{local, surface_id}}).empty());
  return {
      v1::Hello::ROLE_GATEWAY, std::move(name), 0x6A7E, {module}, encode_claims(claims_of(map))};
}

class MemoryRoles : public ::testing::Test {
 protected:
  void SetUp() override {
    NodeMap map;
    ASSERT_TRUE(map.add_module(kModule, {{kLocal, kSurface}}).empty());
    std::vector<GatewayModule> modules;
    GatewayModule m;
    m.id = kModule;
    m.bus = module_bus.connect("gateway");
    modules.push_back(std::move(m));
    gateway = std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules),
                                        quick_tuning());
    surface.start();
    gateway->start();
    link = link_in_memory(io, surface, *gateway);
    ASSERT_TRUE(run_until(io, [&] { return linked(); }));
  }

  void TearDown() override {
    if (gateway) gateway->stop();
    surface.stop();
    master.close();
    node.close();
    EXPECT_TRUE(run_until(io, [&] { return master.done() && node.done(); }));
  }

  bool linked() const { return surface.gateways_ready() == 1 && gateway->connected(); }

  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module"};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  BusRecorder node{io, module_bus.connect("node")};
  // Plain (the memory link proves nothing): the real gateway, and two the scripts play.
  Surface surface{
      io.get_executor(), "surface", surface_bus.connect("surface"),
      SurfacePolicy{
          {{"gw", {kModule}, {kSurface}}, {"other-gw", {7}, {kTheirs}}, {"intruder", {8}, {30}}},
          false},
      quick_tuning()};
  std::unique_ptr<Gateway> gateway;
  backbone::MemoryLinkPair link;
};

TEST_F(MemoryRoles, AFrameFromTheModuleBusReachesTheSurfaceBusTranslated) {
  ASSERT_TRUE(node.send(emcy(kLocal, 1)));
  ASSERT_TRUE(node.send(Frame::standard(0x700u + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] {
    return master.saw(emcy(kSurface, 1)) && master.saw(Frame::standard(0x700u + kSurface, {0x05}));
  })) << gateway->stats_line();
  EXPECT_EQ(master.count(0x080u + kLocal), 0u);
  EXPECT_EQ(master.frames.size(), 2u);
}

TEST_F(MemoryRoles, AnSdoRequestFromTheSurfaceBusReachesTheModuleBus) {
  const Frame request = Frame::standard(0x600u + kSurface, {0x40, 0x17, 0x10, 0, 0, 0, 0, 0});
  ASSERT_TRUE(master.send(request));
  ASSERT_TRUE(run_until(io, [&] {
    return node.saw(Frame::standard(0x600u + kLocal, {0x40, 0x17, 0x10, 0, 0, 0, 0, 0}));
  })) << surface.stats_line();
  // The node's answer comes back under the surface id.
  ASSERT_TRUE(node.send(Frame::standard(0x580u + kLocal, {0x4B, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0})));
  ASSERT_TRUE(run_until(io, [&] {
    return master.saw(Frame::standard(0x580u + kSurface, {0x4B, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0}));
  }));
  EXPECT_EQ(node.count(0x600u + kLocal), 1u);
}

TEST_F(MemoryRoles, ACutLinkAndANewPairDeliverEveryReliableFrameExactlyOnce) {
  constexpr std::uint32_t kFrames = 2000;
  for (std::uint32_t i = 0; i < kFrames / 2; ++i) ASSERT_TRUE(node.send(emcy(kLocal, i)));
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() == kFrames / 2; }));
  // The rest is in flight toward the surface's end (not read yet) when that end is cut: lost
  // with the link, it must go again on the next one.
  link.b->pause_reading(true);
  for (std::uint32_t i = kFrames / 2; i < kFrames; ++i) ASSERT_TRUE(node.send(emcy(kLocal, i)));
  ASSERT_TRUE(run_until(io, [&] { return link.b->unread_bytes() > 0; }));
  link.b->close();
  ASSERT_TRUE(
      run_until(io, [&] { return !gateway->connected() && surface.gateways_ready() == 0; }));
  EXPECT_EQ(master.frames.size(), kFrames / 2);
  link = link_in_memory(io, surface, *gateway);
  ASSERT_TRUE(run_until(io, [&] { return master.frames.size() >= kFrames; }))
      << master.frames.size() << " frames; " << gateway->stats_line();
  // Nothing more comes: no frame twice.
  EXPECT_FALSE(run_until(
      io, [&] { return master.frames.size() > kFrames; }, 200ms));
  ASSERT_EQ(master.frames.size(), kFrames);
  for (std::uint32_t i = 0; i < kFrames; ++i) {
    ASSERT_EQ(master.frames[i], emcy(kSurface, i)) << "frame " << i;
  }
  EXPECT_GT(gateway->counters().session.reliable_resent, 0u);
  EXPECT_EQ(gateway->counters().session.links, 2u);
}

// A refusal whose text is exactly "refused": what a peer that proved nothing is told.
backbone::testing::EnvelopeMatch bare_refusal() {
  return {"a refusal saying only \"refused\"", [](const v1::Envelope& e) {
            return e.has_refusal() && e.refusal().detail() == "refused" &&
                   e.refusal().reason() == v1::Refusal::REASON_UNSPECIFIED;
          }};
}

TEST_F(MemoryRoles, AGatewayClaimingAnotherGatewaysNodeIsRefusedAndToldNothingMore) {
  // A configured gateway, but claiming the real gateway's surface id for a module of its own.
  const PeerIdentity intruder = scripted_gateway("intruder", 8, 9, kSurface);
  PeerScript script;
  script.reply(hello(intruder)).expect(bare_refusal()).expect_closed();
  auto pair = backbone::make_memory_link_pair(io.get_executor());
  ScriptedPeer peer(pair.b, std::move(script));
  surface.attach(pair.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(surface.counters().session.refusals_sent, 1u);
  // The real gateway keeps its link and its nodes.
  EXPECT_TRUE(linked());
  ASSERT_TRUE(master.send(Frame::standard(0x600u + kSurface, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0})));
  ASSERT_TRUE(run_until(io, [&] { return node.count(0x600u + kLocal) == 1; }));
}

TEST_F(MemoryRoles, ANameNotConfiguredIsRefusedLeavingNoTraceInTheTable) {
  const PeerIdentity stranger = scripted_gateway("stranger", 9, 1, 40);
  PeerScript script;
  script.reply(hello(stranger)).expect(bare_refusal()).expect_closed();
  auto pair = backbone::make_memory_link_pair(io.get_executor());
  ScriptedPeer peer(pair.b, std::move(script));
  surface.attach(pair.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(surface.counters().refused_strangers, 1u);
  EXPECT_THAT(surface.stats_line(), ::testing::HasSubstr("1/1 gateway(s) up"));
}

// The forged heartbeat: a bound gateway sending the real gateway's node's heartbeat, NMT
// and SYNC. None reaches the master; each is counted by gateway and reason; its own EMCY does.
TEST_F(MemoryRoles, ABoundGatewaysFramesForNodesNotItsOwnNeverReachTheSurfaceBus) {
  const PeerIdentity other = scripted_gateway("other-gw", 7, 9, kTheirs);
  const Frame forged_heartbeat = Frame::standard(0x700u + kSurface, {0x05});
  const Frame nmt_stop_all = Frame::standard(0x000, {0x81, 0x00});
  const Frame sync = Frame::standard(0x080, {});
  PeerScript script;
  script.reply(hello(other))
      .expect(hello_from(v1::Hello::ROLE_SURFACE))
      .wait_for("both gateways are ready", [&] { return surface.gateways_ready() == 2; })
      .reply(backbone::testing::payload(
          1, frames_payload(7, {forged_heartbeat, nmt_stop_all, sync, emcy(kTheirs, 3)})))
      .wait_for("its EMCY is on the surface bus", [&] { return master.saw(emcy(kTheirs, 3)); })
      .tolerate(backbone::testing::any_keepalive());
  auto pair = backbone::make_memory_link_pair(io.get_executor());
  ScriptedPeer peer(pair.b, std::move(script));
  surface.attach(pair.a);
  ASSERT_TRUE(peer.finishes(io));
  // The real gateway's own heartbeat still passes.
  ASSERT_TRUE(node.send(Frame::standard(0x700u + kLocal, {0x05})));
  ASSERT_TRUE(run_until(io, [&] { return master.saw(forged_heartbeat); }));
  EXPECT_EQ(master.count(0x700u + kSurface), 1u);  // the real one only
  EXPECT_EQ(master.count(0x000), 0u);
  EXPECT_EQ(master.count(0x080), 0u);
  const SurfaceCounters c = surface.counters();
  EXPECT_EQ(c.not_its_own[static_cast<std::size_t>(NotItsOwn::outside_claims)], 1u);
  EXPECT_EQ(c.not_its_own[static_cast<std::size_t>(NotItsOwn::master_only)], 2u);
  ASSERT_EQ(c.not_its_own_by_gateway.size(), 1u);
  EXPECT_EQ(c.not_its_own_by_gateway[0].first, "other-gw");
  EXPECT_THAT(surface.stats_line(),
              ::testing::HasSubstr("not-its-own from 'other-gw': master-only 2 outside-claims 1"));
}

TEST_F(MemoryRoles, AScriptedGatewayWithItsOwnIdsIsAdmittedAndGetsOnlyItsNodesRequests) {
  const PeerIdentity other = scripted_gateway("other-gw", 7, 9, kTheirs);
  const Frame request = Frame::standard(0x600u + kTheirs, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0});
  std::vector<Frame> routed;
  PeerScript script;
  script.reply(hello(other))
      .expect(hello_from(v1::Hello::ROLE_SURFACE))
      .wait_for("both gateways are ready", [&] { return surface.gateways_ready() == 2; })
      .reply(backbone::testing::payload(1, frames_payload(7, {emcy(kTheirs, 3)})))
      .wait_for("its EMCY is on the surface bus", [&] { return master.saw(emcy(kTheirs, 3)); })
      .act("the master asks its node", [&] { master.send(request); })
      .tolerate(backbone::testing::any_keepalive())
      .expect({"a payload with the request for its node", [&](const v1::Envelope& e) {
                 if (e.seq() == 0 || !e.has_payload()) return false;
                 v1::Payload p;
                 const std::span<const std::uint8_t> bytes(
                     reinterpret_cast<const std::uint8_t*>(e.payload().data()), e.payload().size());
                 return !decode_frame_payload(bytes, p, routed) && routed == std::vector{request};
               }});
  auto pair = backbone::make_memory_link_pair(io.get_executor());
  ScriptedPeer peer(pair.b, std::move(script));
  surface.attach(pair.a);
  ASSERT_TRUE(peer.finishes(io));
  // The real gateway's module never saw the other gateway's request.
  EXPECT_FALSE(run_until(
      io, [&] { return !node.frames.empty(); }, 100ms));
  EXPECT_EQ(surface.counters().session.refusals_sent, 0u);
}

}  // namespace
}  // namespace canbridge::bridge
