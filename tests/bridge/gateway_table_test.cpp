// The surface's table of gateways: which hellos may bind (configured and proven names only, each
// within its configured modules and surface ids, no COB-ID claimed twice, no name twice), what a
// bound gateway may send, and which gateway a surface frame is for.
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
  GatewayTable::Hello h{name, session, {}, claims_for(modules), {}};
  for (const auto& m : modules) h.modules.push_back(m.first);
  return h;
}

GatewayTable::Hello default_hello(const std::string& name, std::uint64_t session, ModuleId module) {
  return hello(name, session, {{module, NodeMap::default_pairs(module)}});
}

// The surface's configuration (plain): A module 1, B module 2 (default mapping: 33..63,
// 65..95), C modules 3 and 5 (97..127), Q module 7 at surface id 1, O (no claims) module 4.
std::vector<AcceptedGateway> configured() {
  return {{"gw-a", {1}, {}},
          {"gw-b", {2}, {}},
          {"gw-c", {3, 5}, {}},
          {"gw-q", {7}, {1}},
          {"gw-old", {4}, {2}}};
}

// A and B admitted and connected.
struct TwoGateways : ::testing::Test {
  TwoGateways() {
    a = *table.admit(default_hello("gw-a", 0xA, 1)).id;
    b = *table.admit(default_hello("gw-b", 0xB, 2)).id;
    table.set_connected(a, true);
    table.set_connected(b, true);
  }
  GatewayTable table{"surface-1", configured(), false};
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

TEST_F(TwoGateways, ConfiguredGatewaysAreAdmittedAndKeepTheirIdsByName) {
  EXPECT_NE(a, b);
  const auto again = table.admit(default_hello("gw-a", 0xA, 1));  // A's link came back
  ASSERT_TRUE(again.id);
  EXPECT_EQ(*again.id, a);
  ASSERT_TRUE(table.admit(default_hello("gw-c", 0xC, 3)).id);
  EXPECT_EQ(table.gateways().size(), configured().size());
}

TEST_F(TwoGateways, ANameNotConfiguredIsRefusedLeavingNoEntry) {
  for (int i = 0; i < 1000; ++i) {
    const auto refused = table.admit(default_hello("rogue-" + std::to_string(i), 0x90, 3));
    ASSERT_FALSE(refused.id);
    EXPECT_TRUE(refused.stranger);
    EXPECT_EQ(refused.to_peer, "refused");  // it proved nothing: no names, no modules
    EXPECT_THAT(refused.refusal, HasSubstr("'rogue-" + std::to_string(i) + "' is not configured"));
  }
  EXPECT_EQ(table.gateways().size(), configured().size());
  EXPECT_FALSE(table.find("rogue-1"));
  // The same stranger again is marked repeated: one slot, whatever the names.
  EXPECT_TRUE(table.admit(default_hello("rogue-999", 0x90, 3)).repeated);
  // C, configured for module 3, binds as if nobody had knocked.
  EXPECT_TRUE(table.admit(default_hello("gw-c", 0xC, 3)).id);
}

TEST_F(TwoGateways, AHelloNamingOtherThanItsProvenIdentityIsRefusedWithTheReason) {
  GatewayTable::Hello h = default_hello("gw-c", 0xC, 3);
  h.authenticated_peer = "gw-b";  // B's key, C's name
  const auto refused = table.admit(h);
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("proved identity 'gw-b' but its hello names"));
  EXPECT_EQ(refused.to_peer, refused.refusal);  // a proven peer may learn why
  h.authenticated_peer = "gw-c";
  EXPECT_TRUE(table.admit(h).id);
}

TEST(GatewayTable, ALinkThatProvedNothingBindsNobodyWhenAuthenticationIsOn) {
  GatewayTable table{"surface-1", configured()};
  GatewayTable::Hello h = default_hello("gw-a", 0xA, 1);
  const auto refused = table.admit(h);
  EXPECT_FALSE(refused.id);
  EXPECT_TRUE(refused.stranger);
  EXPECT_EQ(refused.to_peer, "refused");
  EXPECT_THAT(refused.refusal, HasSubstr("proved no identity"));
  h.authenticated_peer = "gw-a";
  EXPECT_TRUE(table.admit(h).id);
}

TEST_F(TwoGateways, AModuleOutsideItsConfigurationIsRefused) {
  const auto refused = table.admit(
      hello("gw-c", 0xC, {{3, NodeMap::default_pairs(3)}, {1, NodeMap::default_pairs(1)}}));
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("gateway 'gw-c' announces module 1"));
  EXPECT_EQ(refused.to_peer, "refused");
}

TEST_F(TwoGateways, ClaimsOutsideItsConfiguredNodesAndTheirCobIdsAreRefused) {
  // Module 5 (C's) mapped onto surface ids 36..38: A's, and outside C's 97..127.
  const auto nodes = table.admit(hello("gw-c", 0xC, {{5, {{1, 36}, {2, 37}, {3, 38}}}}));
  EXPECT_FALSE(nodes.id);
  EXPECT_THAT(nodes.refusal, HasSubstr("gateway 'gw-c' module 5 claims surface node id 36"));
  // Its own node ids, but a COB-ID of none of them (A's node 33's TPDO1).
  GatewayTable::Hello cob{"gw-c", 0xC, {5}, GatewayClaims{{{5, {100}, {{0x1A1, 0x1A1}}}}}, {}};
  const auto cobs = table.admit(cob);
  EXPECT_FALSE(cobs.id);
  EXPECT_THAT(cobs.refusal, HasSubstr("claims surface COB-ID 0x1A1"));
  // Surface ids within its configuration are fine.
  EXPECT_TRUE(table.admit(hello("gw-c", 0xC, {{5, {{1, 100}, {2, 101}}}})).id);
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

TEST_F(TwoGateways, OverlappingCobIdsAreRefusedEvenWhenTheNodeIdsDiffer) {
  // A qd node 1 at surface id 1 owns slots 1..3 too: 0x1A1 (TPDO1 of slot 1) is node 33's TPDO1
  // on A's cia301 module. Within Q's configuration (its node 1's image under any profile), but
  // A holds it.
  GatewayTable::Hello qd{
      "gw-q", 0xD, {7}, GatewayClaims{{{7, {1}, {{0x181, 0x181}, {0x1A1, 0x1A1}}}}}, {}};
  const auto refused = table.admit(qd);
  EXPECT_FALSE(refused.id);
  EXPECT_THAT(refused.refusal, HasSubstr("surface COB-ID 0x1A1 of gateway 'gw-q' module 7 collides "
                                         "with gateway 'gw-a' module 1"));
  EXPECT_THAT(refused.refusal, HasSubstr("gateway 'gw-q' refused"));
}

TEST_F(TwoGateways, ADownGatewaysModulesAndIdsStayItsOwnAndItRebindsAtOnce) {
  table.set_connected(a, false);
  // Another configured gateway announcing A's module while A is down: refused.
  const auto module = table.admit(
      hello("gw-c", 0xC, {{3, NodeMap::default_pairs(3)}, {1, NodeMap::default_pairs(1)}}));
  EXPECT_FALSE(module.id);
  // ... or a COB-ID A's claims hold.
  GatewayTable::Hello qd{"gw-q", 0xD, {7}, GatewayClaims{{{7, {1}, {{0x1A1, 0x1A1}}}}}, {}};
  EXPECT_FALSE(table.admit(qd).id);
  EXPECT_EQ(table.owner_of_node(33), a);
  EXPECT_EQ(table.owner_of_cob(0x1A1), a);
  // A returns (a new process): bound at once, nothing of the rogues in its way.
  const auto back = table.admit(default_hello("gw-a", 0xA2, 1));
  ASSERT_TRUE(back.id);
  EXPECT_EQ(*back.id, a);
  EXPECT_FALSE(back.repeated);
}

TEST_F(TwoGateways, ALiveClaimUpdateOutsideItsConfigurationIsRefusedAndTheOldClaimsStay) {
  // A's node 33 moves to surface id 70: B's.
  const GatewayClaims moved = claims_for({{1, {{1, 70}}}});
  const std::string why = table.update_claims(a, moved);
  EXPECT_THAT(why, HasSubstr("claims surface node id 70"));
  EXPECT_EQ(table.owner_of_node(33), a);
  EXPECT_EQ(table.owner_of_node(70), b);
  // Within its configuration: taken.
  EXPECT_EQ(table.update_claims(a, claims_for({{1, {{1, 40}}}})), "");
  EXPECT_EQ(table.owner_of_node(40), a);
  EXPECT_FALSE(table.owner_of_node(33));
}

TEST_F(TwoGateways, ABoundGatewayMaySendOnlyItsOwnNodesCobIds) {
  auto refuses = [&](GatewayTable::GatewayId g, const can::Frame& f) {
    return table.refuses(g, f);
  };
  // A's: TPDO1, SDO response, heartbeat, EMCY of its nodes 33..63; an LSS answer.
  for (std::uint32_t cob : {0x1A1u, 0x5A5u, 0x725u, 0x0BFu, 0x7E4u}) {
    EXPECT_FALSE(refuses(a, can::Frame::standard(cob, {0})).has_value()) << std::hex << cob;
  }
  // B's node 69 heartbeat, node 5's SDO response (nobody's): not A's.
  EXPECT_EQ(refuses(a, can::Frame::standard(0x745, {5})), NotItsOwn::outside_claims);
  EXPECT_EQ(refuses(a, can::Frame::standard(0x585, {0})), NotItsOwn::outside_claims);
  // The master's own: NMT, SYNC, TIME, LSS requests.
  EXPECT_EQ(refuses(a, can::Frame::standard(0x000, {0x81, 0})), NotItsOwn::master_only);
  EXPECT_EQ(refuses(a, can::Frame::standard(0x080, {})), NotItsOwn::master_only);
  EXPECT_EQ(refuses(a, can::Frame::standard(0x100, {1, 2, 3, 4, 5, 6})), NotItsOwn::master_only);
  EXPECT_EQ(refuses(a, can::Frame::standard(0x7E5, {0x04, 1})), NotItsOwn::master_only);
  EXPECT_EQ(refuses(a, can::Frame::make(0x18FF0001, can::FrameFlags::extended, {1})),
            NotItsOwn::extended);
}

TEST(GatewayTable, OverlappingConfigurationsAreRefusedAtStart) {
  EXPECT_THROW(GatewayTable("s", {{"x", {1}, {}}, {"y", {1}, {}}}), std::invalid_argument);
  EXPECT_THROW(GatewayTable("s", {{"x", {1}, {}}, {"y", {5}, {40}}}), std::invalid_argument);
  EXPECT_THROW(GatewayTable("s", {{"x", {1}, {}}, {"x", {2}, {}}}), std::invalid_argument);
  EXPECT_NO_THROW(GatewayTable("s", {{"x", {1}, {}}, {"y", {5}, {20}}}));
}

TEST_F(TwoGateways, ARefusalIsMarkedRepeatedUntilItsReasonChanges) {
  auto with_module_1 = [](std::uint64_t session) {
    return hello("gw-c", session, {{3, NodeMap::default_pairs(3)}, {1, NodeMap::default_pairs(1)}});
  };
  const auto first = table.admit(with_module_1(0xC));
  EXPECT_FALSE(first.repeated);
  const auto second = table.admit(with_module_1(0xC));
  EXPECT_TRUE(second.repeated);
  EXPECT_EQ(second.refusal, first.refusal);
  const auto other_reason = table.admit(hello("gw-c", 0xC, {{5, {{1, 36}}}}));
  EXPECT_FALSE(other_reason.repeated);
  // Admitted once, then refused for the first reason again: reported again.
  ASSERT_TRUE(table.admit(default_hello("gw-c", 0xC, 3)).id);
  EXPECT_FALSE(table.admit(with_module_1(0xC2)).repeated);
}

TEST_F(TwoGateways, AGatewayWithoutClaimsIsCheckedByModuleOnly) {
  GatewayTable::Hello legacy{"gw-old", 0xE, {4}, std::nullopt, {}};
  const auto old = table.admit(legacy);
  ASSERT_TRUE(old.id);
  // Without claims it may send what its configured node (surface id 2) may.
  EXPECT_FALSE(table.refuses(*old.id, can::Frame::standard(0x702, {5})));
  EXPECT_EQ(table.refuses(*old.id, can::Frame::standard(0x703, {5})), NotItsOwn::outside_claims);
  GatewayTable::Hello legacy_other{"gw-old", 0xF, {1}, std::nullopt, {}};
  table.set_connected(*old.id, false);
  EXPECT_FALSE(table.admit(legacy_other).id);
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
