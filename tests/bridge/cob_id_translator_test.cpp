#include "routing/cob_id_translator.hpp"

#include <gtest/gtest.h>

#include <vector>

#include "tests/bridge/translator_probe.hpp"

namespace canbridge::bridge {
namespace {

using can::Frame;

// Modules 1 and 2 with the default map: module m's node n is surface node n + 32m.
class TranslatorTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());
    ASSERT_TRUE(map.add_module(2, NodeMap::default_pairs(2)).empty());
  }
  std::vector<std::pair<std::size_t, Frame>> route(const Frame& f) {
    return testing::routes(translator, f);
  }
  std::uint64_t drops(DropReason r) const { return translator.dropped(r); }
  NodeMap map;
  CobIdTranslator translator{map};
};

TEST_F(TranslatorTest, EveryNodeAddressedFunctionMapsBothWays) {
  const std::uint16_t bases[] = {0x080, 0x180, 0x200, 0x280, 0x300, 0x380,
                                 0x400, 0x480, 0x500, 0x580, 0x600, 0x700};
  for (std::uint16_t base : bases) {
    for (NodeId local : {NodeId{1}, NodeId{2}, NodeId{31}}) {
      const Frame on_module = Frame::standard(base + local, {0xAA});
      auto up = translator.to_surface(1, on_module);  // module index 1 = module id 2
      ASSERT_TRUE(up) << std::hex << base;
      EXPECT_EQ(up->id, base + local + 64u);
      auto down = route(*up);
      ASSERT_EQ(down.size(), 1u);
      EXPECT_EQ(down[0].first, 1u);
      EXPECT_EQ(down[0].second, on_module);
    }
  }
}

TEST_F(TranslatorTest, IssueExampleSdoRequestGoesOnlyToOwner) {
  auto out = route(Frame::standard(0x622, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].first, 0u);  // module id 1
  EXPECT_EQ(out[0].second.id, 0x602u);
  EXPECT_EQ(translator.to_surface(0, Frame::standard(0x582, {0x43}))->id, 0x5A2u);
}

TEST_F(TranslatorTest, NmtNodeSpecificRewritesByteOneAndBroadcastReachesAll) {
  auto specific = route(Frame::standard(0x000, {0x01, 0x22}));
  ASSERT_EQ(specific.size(), 1u);
  EXPECT_EQ(specific[0].first, 0u);
  EXPECT_EQ(specific[0].second, Frame::standard(0x000, {0x01, 0x02}));

  auto broadcast = route(Frame::standard(0x000, {0x80, 0x00}));
  ASSERT_EQ(broadcast.size(), 2u);
  EXPECT_EQ(broadcast[0].second, Frame::standard(0x000, {0x80, 0x00}));
  EXPECT_EQ(broadcast[1].first, 1u);
}

TEST_F(TranslatorTest, SyncAndTimeFanOut) {
  EXPECT_EQ(route(Frame::standard(0x080, {})).size(), 2u);
  EXPECT_EQ(route(Frame::standard(0x100, {1, 2, 3, 4, 5, 6})).size(), 2u);
}

TEST_F(TranslatorTest, UnmappedFramesAreCountedNeverForwarded) {
  EXPECT_TRUE(route(Frame::standard(0x601, {})).empty());  // surface node 1: module 0 absent
  EXPECT_TRUE(route(Frame::standard(0x000, {0x01, 0x7F})).empty());
  EXPECT_EQ(drops(DropReason::unknown_node), 2u);
  EXPECT_TRUE(route(Frame::standard(0x000, {0x01})).empty());
  EXPECT_EQ(drops(DropReason::malformed_nmt), 1u);
  EXPECT_TRUE(route(Frame::from_span(0x18FF0001, {}, can::FrameFlags::extended)).empty());
  EXPECT_EQ(drops(DropReason::extended_id), 1u);
  EXPECT_TRUE(route(Frame::standard(0x7E5, {0x04, 0x01})).empty());  // LSS: no module selected
  EXPECT_EQ(drops(DropReason::lss_unrouted), 1u);
  EXPECT_TRUE(route(Frame::standard(0x7E0, {})).empty());  // reserved
  EXPECT_EQ(drops(DropReason::not_routable), 1u);

  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x000, {0x01, 0x00})));  // module NMT
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x080, {})));            // module SYNC
  EXPECT_EQ(drops(DropReason::not_routable), 3u);
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x1A0, {})));  // local node 32: unmapped
  EXPECT_EQ(drops(DropReason::unknown_node), 3u);
}

TEST_F(TranslatorTest, SetNodeIdCommandsAreTranslatedWithinTheOwningModuleOnly) {
  // `E0 cc nn` with surface ids: both become module 1's local ids.
  auto change = route(Frame::standard(0x000, {0xE0, 0x25, 0x29}));
  ASSERT_EQ(change.size(), 1u);
  EXPECT_EQ(change[0].first, 0u);
  EXPECT_EQ(change[0].second, Frame::standard(0x000, {0xE0, 0x05, 0x09}));
  // Onto a node of module 2: refused, counted, sent nowhere, the reason kept for the log.
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE0, 0x25, 0x45})).empty());
  EXPECT_EQ(drops(DropReason::rename_refused), 1u);
  EXPECT_EQ(translator.rename_refusal().next_surface, 0x45);
  ASSERT_TRUE(translator.rename_refusal().node);
  EXPECT_EQ(translator.rename_refusal().node->local, 5);
  EXPECT_NE(translator.rename_refusal().reason.find("module 2 node 5, on another bus"),
            std::string::npos)
      << translator.rename_refusal().reason;
  EXPECT_EQ(map.planned_move(0, 5), 0);
  // `E1 nn serial`: the new id is byte 1; the serial passes untouched.
  auto by_serial = route(Frame::standard(0x000, {0xE1, 0x47, 0x12, 0x34, 0xAB, 0xCD}));
  ASSERT_EQ(by_serial.size(), 1u);
  EXPECT_EQ(by_serial[0].first, 1u);
  EXPECT_EQ(by_serial[0].second, Frame::standard(0x000, {0xE1, 0x07, 0x12, 0x34, 0xAB, 0xCD}));
  // A malformed E0 (new id 0) is not a rename: it goes like any NMT frame to byte 1's owner, and
  // the node ignores it (docs/nmt-node-id.md).
  auto malformed = route(Frame::standard(0x000, {0xE0, 0x25, 0x00}));
  ASSERT_EQ(malformed.size(), 1u);
  EXPECT_EQ(malformed[0].second, Frame::standard(0x000, {0xE0, 0x05, 0x00}));
}

// Issue 14: a free surface id is no longer refused. The node keeps its local id (`E0 cc cc`, a
// reset communication it confirms with its boot-up) and the move is planned in the live map.
TEST_F(TranslatorTest, SetNodeIdToAFreeSurfaceIdPlansTheMove) {
  auto to_free = route(Frame::standard(0x000, {0xE0, 0x25, 0x01}));  // surface 1: nobody's
  ASSERT_EQ(to_free.size(), 1u);
  EXPECT_EQ(to_free[0].first, 0u);
  EXPECT_EQ(to_free[0].second, Frame::standard(0x000, {0xE0, 0x05, 0x05}));
  EXPECT_EQ(map.planned_move(0, 5), 1);
  EXPECT_EQ(map.surface_of(0, 5), 0x25);  // not before the boot-up confirms it
  EXPECT_EQ(drops(DropReason::rename_refused), 0u);
  // Any free id up to 127 on a cia301 module.
  ASSERT_EQ(route(Frame::standard(0x000, {0xE0, 0x26, 0x7F})).size(), 1u);
  EXPECT_EQ(map.planned_move(0, 6), 0x7F);
  // Outside 1..127, or by serial to an id no module maps (which bus?): refused with a reason.
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE0, 0x25, 0x80})).empty());
  EXPECT_NE(translator.rename_refusal().reason.find("outside 1..127"), std::string::npos)
      << translator.rename_refusal().reason;
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE1, 0x01, 0x12, 0x34, 0xAB, 0xCD})).empty());
  EXPECT_FALSE(translator.rename_refusal().node);
  EXPECT_NE(translator.rename_refusal().reason.find("by serial"), std::string::npos);
  EXPECT_EQ(drops(DropReason::rename_refused), 2u);
  EXPECT_EQ(map.planned_move(0, 5), 1);  // refusals plan nothing
}

// The profile bounds the free ids: a pdop node keeps its id in 5 bits, and its surface id's
// COB-IDs (S, S + 32, S + 64, S + 96 in every function) must not be another module's.
TEST(TranslatorProfiles, SetNodeIdToAFreeSurfaceIdWithinWhatTheProfileAllows) {
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, {{10, 42}, {11, 43}}).empty());
  ASSERT_TRUE(map.add_module(2, {{1, 3}, {2, 4}}, IdProfile::pdop).empty());
  CobIdTranslator translator{map};
  const auto route = [&](const Frame& f) { return testing::routes(translator, f); };
  auto ok = route(Frame::standard(0x000, {0xE0, 3, 9}));
  ASSERT_EQ(ok.size(), 1u);
  EXPECT_EQ(ok[0].second, Frame::standard(0x000, {0xE0, 1, 1}));
  EXPECT_EQ(map.planned_move(1, 1), 9);
  // 33: above the pdop range.
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE0, 4, 33})).empty());
  EXPECT_NE(translator.rename_refusal().reason.find("outside 1..31"), std::string::npos)
      << translator.rename_refusal().reason;
  // 10: free as a node id, but the cia301 node 42 owns 0x1AA = TPDO1 t=1 of surface 10.
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE0, 4, 10})).empty());
  EXPECT_NE(translator.rename_refusal().reason.find("collides with module 1"), std::string::npos)
      << translator.rename_refusal().reason;
  // A cia301 node cannot take a surface id whose COB-IDs a pdop node holds (3 + 32 = 35).
  EXPECT_TRUE(route(Frame::standard(0x000, {0xE0, 42, 35})).empty());
  EXPECT_EQ(translator.dropped(DropReason::rename_refused), 3u);
  EXPECT_EQ(map.planned_move(1, 2), 0);
}

TEST_F(TranslatorTest, LssReachesOnlyTheSelectedModuleWithNodeIdsTranslated) {
  translator.route_lss_to(1);  // module id 2: surface = local + 64
  auto switch_global = route(Frame::standard(0x7E5, {0x04, 0x01, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(switch_global.size(), 1u);
  EXPECT_EQ(switch_global[0].first, 1u);
  EXPECT_EQ(switch_global[0].second, Frame::standard(0x7E5, {0x04, 0x01, 0, 0, 0, 0, 0, 0}));
  // Configure node-id: the surface id the master asks for becomes the module's local id.
  auto configure = route(Frame::standard(0x7E5, {0x11, 0x4A, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(configure.size(), 1u);
  EXPECT_EQ(configure[0].second, Frame::standard(0x7E5, {0x11, 0x0A, 0, 0, 0, 0, 0, 0}));
  auto unconfigure = route(Frame::standard(0x7E5, {0x11, 0xFF, 0, 0, 0, 0, 0, 0}));
  ASSERT_EQ(unconfigure.size(), 1u);
  EXPECT_EQ(unconfigure[0].second.data[1], 0xFF);
  // A surface id of module 1 cannot be configured on module 2's bus.
  EXPECT_TRUE(route(Frame::standard(0x7E5, {0x11, 0x25, 0, 0, 0, 0, 0, 0})).empty());
  EXPECT_EQ(drops(DropReason::unknown_node), 1u);

  // Responses: only from the selected module; the inquired node id as the surface sees it.
  auto inquired = translator.to_surface(1, Frame::standard(0x7E4, {0x5E, 0x0A, 0, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(inquired);
  EXPECT_EQ(*inquired, Frame::standard(0x7E4, {0x5E, 0x4A, 0, 0, 0, 0, 0, 0}));
  auto identify = translator.to_surface(1, Frame::standard(0x7E4, {0x50, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(identify);
  EXPECT_EQ(identify->data[0], 0x50);
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x7E4, {0x50, 0, 0, 0, 0, 0, 0, 0})));
  EXPECT_EQ(drops(DropReason::lss_unrouted), 1u);
}

TEST_F(TranslatorTest, RemoteFramesKeepTheirFlag) {
  Frame guard;
  guard.id = 0x705;
  guard.flags = can::FrameFlags::remote;
  guard.len = 1;
  auto up = translator.to_surface(0, guard);
  ASSERT_TRUE(up);
  EXPECT_EQ(up->id, 0x725u);
  EXPECT_TRUE(up->is_remote());
}

TEST(NodeMap, RefusesOverlapNamingTheOwner) {
  NodeMap map;
  ASSERT_TRUE(map.add_module(0, NodeMap::default_pairs(0)).empty());
  auto problems = map.add_module(5, {{1, 40}, {2, 3}, {3, 0}, {3, 41}});
  ASSERT_EQ(problems.size(), 2u);
  EXPECT_NE(problems[0].find("already owned by module 0 node 3"), std::string::npos) << problems[0];
  EXPECT_NE(problems[1].find("must be 1..127"), std::string::npos);
  EXPECT_EQ(map.modules().size(), 1u);
  EXPECT_FALSE(map.add_module(0, {{1, 100}}).empty());  // module id twice
  EXPECT_TRUE(NodeMap::default_pairs(4).empty());
  EXPECT_EQ(NodeMap::default_pairs(3).back().second, 127);
}

// The default map puts module 1 on surface 33..63: a qd module 0 owns those COB-IDs as its
// slot 1, so the two cannot share a gateway (the operator maps one of them elsewhere).
TEST_F(TranslatorTest, QdModuleOnTheDefaultMapCollidesWithTheNextModule) {
  auto problems = map.add_module(0, NodeMap::default_pairs(0), IdProfile::qd);
  ASSERT_FALSE(problems.empty());
  EXPECT_NE(problems[0].find("COB-ID 0x1A1: module 0 (qd) local node 1 -> surface 1 TPDO2 "
                             "collides with module 1 (cia301) local node 1 -> surface 33 TPDO1"),
            std::string::npos)
      << problems[0];
  EXPECT_EQ(map.modules().size(), 2u);
  // Existing routing is untouched by the refused module.
  EXPECT_EQ(translator.to_surface(0, Frame::standard(0x181, {}))->id, 0x1A1u);
}

}  // namespace
}  // namespace canbridge::bridge
