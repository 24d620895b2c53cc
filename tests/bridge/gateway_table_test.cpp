// The surface's table of gateways: which hellos may bind (no module, surface node id or COB-ID
// claimed twice among connected gateways, no name twice), and which gateway a surface frame is for.
#include "bridge/gateway_table.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bridge/gateway_claims.hpp"
#include "routing/node_map.hpp"

namespace canbridge::bridge {
namespace {

using ::testing::HasSubstr;

// The claims of one gateway serving `modules` with the given (local, surface) pairs each.
GatewayClaims claims_for(
    const std::vector<std::pair<ModuleId, std::vector<std::pair<NodeId, NodeId>>>>& modules,
    IdProfile profile = IdProfile::cia301) {
  NodeMap map;
  for (const auto& [id, pairs] : modules) EXPECT_TRUE(map.add_module(id, pairs, profile).empty());
  return claims_of(map);
}

GatewayTable::Hello hello(
    const std::string& name, std::uint64_t session,
    const std::vector<std::pair<ModuleId, std::vector<std::pair<NodeId, NodeId>>>>& modules) {
  GatewayTable::Hello h{name, session, {}, claims_for(modules)};
  for (const auto& m : modules) h.modules.push_back(m.first);
  return h;
}

GatewayTable::Hello default_hello(const std::string& name, std::uint64_t session, ModuleId module) {
  return hello(name, session, {{module, NodeMap::default_pairs(module)}});
}

// A and B admitted and connected: A serves module 1 (surface 33..63), B module 2 (65..95).
struct TwoGateways : ::testing::Test {
  TwoGateways() {
    a = *table.admit(default_hello("gw-a", 0xA, 1)).id;
    b = *table.admit(default_hello("gw-b", 0xB, 2)).id;
    table.set_connected(a, true);
    table.set_connected(b, true);
  }
  GatewayTable table{"surface-1"};
  GatewayTable::GatewayId a = 0;
  GatewayTable::GatewayId b = 0;
};

TEST(GatewayClaims, ClaimsListTheModulesSurfaceIdsAndCobRangesAndSurviveTheWire) {
  const GatewayClaims claims = claims_for({{1, NodeMap::default_pairs(1)}});
  ASSERT_EQ(claims.modules.size(), 1u);
  const ModuleClaim& m = claims.modules[0];
  EXPECT_EQ(m.id, 1u);
  ASSERT_EQ(m.surface_nodes.size(), 31u);
  EXPECT_EQ(m.surface_nodes.front(), 33);
  EXPECT_EQ(m.surface_nodes.back(), 63);
  // One range per function code: EMCY, TPDO1..RPDO4, SDO tx/rx, heartbeat.
  ASSERT_EQ(m.cob_ranges.size(), 12u);
  EXPECT_EQ(m.cob_ranges.front(), (CobRange{0x0A1, 0x0BF}));
  EXPECT_EQ(m.cob_ranges.back(), (CobRange{0x721, 0x73F}));
  const auto back = decode_claims(encode_claims(claims));
  ASSERT_TRUE(back);
  EXPECT_EQ(*back, claims);
}

TEST(GatewayClaims, ClaimsNamingImpossibleIdsAreNotRead) {
  GatewayClaims bad_node{{{1, {128}, {}}}};
  EXPECT_FALSE(decode_claims(encode_claims(bad_node)));
  GatewayClaims bad_cob{{{1, {5}, {{0x7F0, 0x800}}}}};
  EXPECT_FALSE(decode_claims(encode_claims(bad_cob)));
  GatewayClaims reversed{{{1, {5}, {{0x185, 0x181}}}}};
  EXPECT_FALSE(decode_claims(encode_claims(reversed)));
  EXPECT_FALSE(decode_claims("\xFF\xFF\xFF"));
}

TEST_F(TwoGateways, DisjointGatewaysAreAdmittedAndKeepTheirIdsByName) {
  EXPECT_NE(a, b);
  const auto again = table.admit(default_hello("gw-a", 0xA, 1));  // A's link came back
  ASSERT_TRUE(again.id);
  EXPECT_EQ(*again.id, a);
  ASSERT_TRUE(table.admit(default_hello("gw-c", 0xC, 3)).id);
  EXPECT_EQ(table.gateways().size(), 3u);
}

TEST_F(TwoGateways, AModuleAnotherConnectedGatewayServesIsRefusedNamingBothAndTheFix) {
  const auto refused = table.admit(default_hello("gw-c", 0xC, 1));
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("module 1 is already served by gateway 'gw-a'"));
  EXPECT_THAT(refused.refusal, HasSubstr("gateway 'gw-c' refused"));
  EXPECT_THAT(refused.refusal, HasSubstr("give this gateway another name or module"));
}

TEST_F(TwoGateways, ASecondProcessWithAConnectedNameIsRefused) {
  const auto refused = table.admit(default_hello("gw-a", 0xA2, 1));
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("another gateway named 'gw-a' is already connected"));
  EXPECT_THAT(refused.refusal, HasSubstr("give this gateway another name"));
  // Once the old process's link is gone, the new process takes the name over.
  table.set_connected(a, false);
  const auto admitted = table.admit(default_hello("gw-a", 0xA2, 1));
  ASSERT_TRUE(admitted.id);
  EXPECT_EQ(*admitted.id, a);
}

TEST_F(TwoGateways, OverlappingSurfaceNodeIdsAreRefusedNamingBothGatewaysAndModules) {
  // Module 5 maps its local nodes 1..3 onto surface ids 36..38: module 1's (gateway A).
  const auto refused = table.admit(hello("gw-c", 0xC, {{5, {{1, 36}, {2, 37}, {3, 38}}}}));
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal,
              HasSubstr("surface node id 36 of gateway 'gw-c' module 5 is already gateway "
                        "'gw-a' module 1's"));
  EXPECT_THAT(refused.refusal, HasSubstr("(3 ids overlap in all)"));
  EXPECT_THAT(refused.refusal, HasSubstr("map its nodes to surface ids gateway 'gw-a' does not"));
  // Surface ids nobody uses are fine.
  EXPECT_TRUE(table.admit(hello("gw-c", 0xC, {{5, {{1, 100}, {2, 101}}}})).id);
}

TEST_F(TwoGateways, OverlappingCobIdsAreRefusedEvenWhenTheNodeIdsDiffer) {
  // A qd node 1 at surface id 1 owns slots 1..3 too: 0x1A1 (TPDO1 of slot 1) is node 33's TPDO1
  // on A's cia301 module. Hand-made claims: the node ids do not overlap, one COB-ID range does.
  GatewayTable::Hello qd{
      "gw-q", 0xD, {7}, GatewayClaims{{{7, {1}, {{0x181, 0x181}, {0x1A1, 0x1A1}}}}}};
  const auto refused = table.admit(qd);
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("surface COB-ID 0x1A1 of gateway 'gw-q' module 7 collides "
                                         "with gateway 'gw-a' module 1"));
  EXPECT_THAT(refused.refusal, HasSubstr("gateway 'gw-q' refused"));
}

TEST_F(TwoGateways, OnlyConnectedGatewaysRefuseAndAnAdmittedOneTakesOverTheirIds) {
  table.set_connected(a, false);
  const auto c = table.admit(hello("gw-c", 0xC, {{5, {{1, 36}}}}));
  ASSERT_TRUE(c.id);
  EXPECT_EQ(table.owner_of_node(36), *c.id);
  EXPECT_EQ(table.owner_of_node(37), a);  // A keeps what nobody else took
  EXPECT_EQ(table.owner_of_cob(0x600 + 36), *c.id);
  table.set_connected(*c.id, true);
  // A comes back: its node 36 is C's now.
  const auto back = table.admit(default_hello("gw-a", 0xA, 1));
  EXPECT_FALSE(back.id);
  EXPECT_THAT(back.refusal, HasSubstr("gateway 'gw-c' module 5"));
}

TEST_F(TwoGateways, ARefusalIsMarkedRepeatedUntilItsReasonChanges) {
  const auto first = table.admit(default_hello("gw-c", 0xC, 1));
  EXPECT_FALSE(first.repeated);
  const auto second = table.admit(default_hello("gw-c", 0xC, 1));
  EXPECT_TRUE(second.repeated);
  EXPECT_EQ(second.refusal, first.refusal);
  const auto other_reason = table.admit(default_hello("gw-c", 0xC, 2));
  EXPECT_FALSE(other_reason.repeated);
  // Another name's refusal is its own.
  EXPECT_FALSE(table.admit(default_hello("gw-d", 0xD, 1)).repeated);
  // Admitted once, then refused for the first reason again: reported again.
  table.set_connected(a, false);
  ASSERT_TRUE(table.admit(default_hello("gw-c", 0xC, 1)).id);
  table.set_connected(a, true);
  EXPECT_FALSE(table.admit(default_hello("gw-c", 0xC2, 1)).repeated);
}

TEST_F(TwoGateways, AGatewayWithoutClaimsIsCheckedByModuleOnly) {
  GatewayTable::Hello legacy{"gw-old", 0xE, {4}, std::nullopt};
  ASSERT_TRUE(table.admit(legacy).id);
  GatewayTable::Hello legacy_dup{"gw-old2", 0xF, {1}, std::nullopt};
  EXPECT_FALSE(table.admit(legacy_dup).id);
}

TEST_F(TwoGateways, NodeAddressedFramesGoToTheirOwnerBroadcastsToAll) {
  using Route = GatewayTable::Route;
  auto route = [&](const can::Frame& f) { return table.route(f); };
  // SDO request to 37 (A), TPDO1 to 69 (B) as an RPDO, heartbeat from the surface of node 40.
  EXPECT_EQ(route(can::Frame::standard(0x625, {0x40, 0, 0x10, 0, 0, 0, 0, 0})).kind, Route::one);
  EXPECT_EQ(route(can::Frame::standard(0x625, {0x40})).gateway, a);
  EXPECT_EQ(route(can::Frame::standard(0x245, {1})).gateway, b);
  EXPECT_EQ(route(can::Frame::standard(0x728, {5})).gateway, a);
  // NMT to one node: its owner; NMT to all, SYNC, TIME: everybody.
  const auto nmt_b = route(can::Frame::standard(0x000, {0x01, 69}));
  EXPECT_EQ(nmt_b.kind, Route::one);
  EXPECT_EQ(nmt_b.gateway, b);
  EXPECT_EQ(route(can::Frame::standard(0x000, {0x01, 0})).kind, Route::all);
  EXPECT_EQ(route(can::Frame::standard(0x080, {})).kind, Route::all);
  EXPECT_EQ(route(can::Frame::standard(0x100, {1, 2, 3, 4, 5, 6})).kind, Route::all);
  // Nodes nobody claims (1..31, 127): not forwarded, with a reason.
  const auto nobody = route(can::Frame::standard(0x605, {0x40}));
  EXPECT_EQ(nobody.kind, Route::unclaimed);
  EXPECT_EQ(nobody.reason, Unrouted::unclaimed_node);
  EXPECT_EQ(route(can::Frame::standard(0x000, {0x81, 127})).kind, Route::unclaimed);
  // Not any node's: LSS, extended frames: every gateway's translator decides.
  EXPECT_EQ(route(can::Frame::standard(0x7E5, {0x04, 1})).kind, Route::all);
  EXPECT_EQ(route(can::Frame::make(0x18FF0001, can::FrameFlags::extended, {1})).kind, Route::all);
}

}  // namespace
}  // namespace canbridge::bridge
