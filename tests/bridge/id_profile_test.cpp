#include "routing/id_profile.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>
#include <vector>

#include "routing/cob_id_translator.hpp"
#include "tests/bridge/translator_probe.hpp"

namespace canbridge::bridge {
namespace {

using can::Frame;

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

// One module per test, on module index 0, plus whatever the test adds; frames go both ways.
class ProfileTest : public ::testing::Test {
 protected:
  std::vector<std::pair<std::size_t, Frame>> route(const Frame& f) {
    return testing::routes(translator, f);
  }
  std::uint64_t drops(DropReason r) const { return translator.dropped(r); }
  // local on module `m` -> surface (expected), and the surface frame routes back to exactly it.
  void expect_both_ways(std::size_t m, std::uint16_t local, std::uint16_t surface) {
    const Frame on_module = Frame::standard(local, {0x11, 0x22});
    auto up = translator.to_surface(m, on_module);
    ASSERT_TRUE(up) << std::hex << "local 0x" << local;
    EXPECT_EQ(up->id, surface) << std::hex << "local 0x" << local;
    auto down = route(*up);
    ASSERT_EQ(down.size(), 1u) << std::hex << "surface 0x" << surface;
    EXPECT_EQ(down[0].first, m);
    EXPECT_EQ(down[0].second, on_module);
  }
  NodeMap map;
  CobIdTranslator translator{map};
};

TEST(IdProfile, NamesParseAndNodeRanges) {
  for (IdProfile p : {IdProfile::cia301, IdProfile::pdop, IdProfile::qd}) {
    EXPECT_EQ(parse_id_profile(to_string(p)), p);
  }
  EXPECT_FALSE(parse_id_profile("CiA301"));
  EXPECT_FALSE(parse_id_profile(""));
  EXPECT_EQ(max_node_id(IdProfile::cia301), 127);
  EXPECT_EQ(max_node_id(IdProfile::pdop), 31);
  EXPECT_EQ(max_node_id(IdProfile::qd), 31);
  // cia301: 12 functions; pdop: 4 + 8 x 4 + ack; qd: EMCY, 34 TPDOs, 4 RPDOs, SDO x2, HB, loader.
  EXPECT_EQ(profile_cob_ids(IdProfile::cia301).size(), 12u);
  EXPECT_EQ(profile_cob_ids(IdProfile::pdop).size(), 37u);
  EXPECT_EQ(profile_cob_ids(IdProfile::qd).size(), 43u);
  for (IdProfile p : {IdProfile::cia301, IdProfile::pdop, IdProfile::qd}) {
    std::set<std::uint16_t> bases;
    for (const auto& id : profile_cob_ids(p)) {
      EXPECT_TRUE(bases.insert(id.base).second) << to_string(p) << " " << id.name;
      EXPECT_EQ(id.base & (p == IdProfile::cia301 ? 0x7F : 0x1F), 0) << id.name;
    }
  }
}

TEST(IdProfile, QdTpdosFollowTheSimNodesTable) {
  const std::uint16_t expected[34] = {0x180, 0x1A0, 0x1C0, 0x1E0, 0x220, 0x240, 0x260, 0x280, 0x2A0,
                                      0x2C0, 0x2E0, 0x320, 0x340, 0x360, 0x380, 0x3A0, 0x3C0, 0x3E0,
                                      0x420, 0x440, 0x460, 0x480, 0x4A0, 0x4C0, 0x4E0, 0x520, 0x540,
                                      0x560, 0x5A0, 0x5C0, 0x5E0, 0x620, 0x640, 0x660};
  const auto& ids = profile_cob_ids(IdProfile::qd);
  for (unsigned tpdo = 1; tpdo <= 34; ++tpdo) {
    const std::string name = "TPDO" + std::to_string(tpdo);
    auto it = std::find_if(ids.begin(), ids.end(), [&](const auto& id) { return id.name == name; });
    ASSERT_NE(it, ids.end()) << name;
    EXPECT_EQ(it->base, expected[tpdo - 1]) << name;
  }
}

TEST_F(ProfileTest, Cia301EveryFunctionEdgeNodesBothWays) {
  ASSERT_TRUE(map.add_module(0, {{1, 1}, {31, 31}, {127, 127}}, IdProfile::cia301).empty());
  const std::uint16_t bases[] = {0x080, 0x180, 0x200, 0x280, 0x300, 0x380,
                                 0x400, 0x480, 0x500, 0x580, 0x600, 0x700};
  for (std::uint16_t base : bases) {
    for (std::uint16_t node : {1, 31, 127}) expect_both_ways(0, base + node, base + node);
  }
}

TEST_F(ProfileTest, PdopEveryFunctionAndToggleContinuedBitsCarryThrough) {
  // Local 1 -> surface 31 and local 31 -> surface 1: the node id is replaced, bits 6-5 kept.
  ASSERT_TRUE(map.add_module(0, {{1, 31}, {31, 1}}, IdProfile::pdop).empty());
  for (std::uint16_t base : {0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480, 0x500}) {
    for (std::uint16_t tc : {0x00, 0x20, 0x40, 0x60}) {
      expect_both_ways(0, base | tc | 1, base | tc | 31);
      expect_both_ways(0, base | tc | 31, base | tc | 1);
    }
  }
  for (std::uint16_t base : {0x080, 0x580, 0x600, 0x680, 0x700}) {
    expect_both_ways(0, base + 1, base + 31);
    expect_both_ways(0, base + 31, base + 1);
  }
  // Bits 6-5 are not t/c outside the PDOs: 0x5A1 is no pdop COB-ID, though a CiA 301 shape.
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x5A1, {})));
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x721, {})));
  EXPECT_EQ(drops(DropReason::not_routable), 2u);
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x1A2, {})));  // node 2: unmapped
  EXPECT_EQ(drops(DropReason::unknown_node), 1u);
}

TEST_F(ProfileTest, QdEverySlotTpdo1To34AndLoaderBootUpBothWays) {
  ASSERT_TRUE(map.add_module(0, {{1, 31}, {31, 1}}, IdProfile::qd).empty());
  for (const auto& id : profile_cob_ids(IdProfile::qd)) {
    expect_both_ways(0, id.base + 1, id.base + 31);
    expect_both_ways(0, id.base + 31, id.base + 1);
  }
  expect_both_ways(0, 0x721, 0x73F);       // loader boot-up of local node 1
  expect_both_ways(0, 0x660 + 31, 0x661);  // TPDO34
  expect_both_ways(0, 0x1A1, 0x1BF);       // TPDO2, slot 1
  // EMCY and heartbeat are slot 0 only (slots 1..3 of the other functions are TPDOs).
  for (std::uint16_t unowned : {0x0A1, 0x0C1, 0x0E1, 0x741, 0x761}) {
    EXPECT_FALSE(translator.to_surface(0, Frame::standard(unowned, {}))) << std::hex << unowned;
  }
  EXPECT_EQ(drops(DropReason::not_routable), 5u);
  EXPECT_FALSE(translator.to_surface(0, Frame::standard(0x1A2, {})));  // node 2: unmapped
  EXPECT_EQ(drops(DropReason::unknown_node), 1u);
  EXPECT_TRUE(route(Frame::standard(0x1A2, {})).empty());  // surface 0x1A2: nobody's
  EXPECT_EQ(drops(DropReason::unknown_node), 2u);
}

TEST_F(ProfileTest, NmtNodeSpecificReachesSlotZeroOwnerBroadcastReachesAll) {
  ASSERT_TRUE(map.add_module(0, {{5, 7}}, IdProfile::qd).empty());
  ASSERT_TRUE(map.add_module(1, {{5, 100}}, IdProfile::cia301).empty());
  auto specific = route(Frame::standard(0x000, {0x81, 7}));
  ASSERT_EQ(specific.size(), 1u);
  EXPECT_EQ(specific[0].first, 0u);
  EXPECT_EQ(specific[0].second, Frame::standard(0x000, {0x81, 5}));
  EXPECT_TRUE(route(Frame::standard(0x000, {0x81, 7 + 32})).empty());  // slot 1: no NMT node
  EXPECT_EQ(route(Frame::standard(0x000, {0x01, 0})).size(), 2u);
  expect_both_ways(1, 0x585, 0x5E4);
}

TEST(IdProfileNodeMap, PdopAndQdNodesAbove31AreRefused) {
  for (IdProfile p : {IdProfile::pdop, IdProfile::qd}) {
    NodeMap map;
    auto problems = map.add_module(3, {{1, 32}, {32, 2}, {3, 3}}, p);
    ASSERT_EQ(problems.size(), 2u) << to_string(p);
    EXPECT_TRUE(contains(problems[0], "module 3 node 1 (" + std::string(to_string(p)) +
                                          "): surface node id 32 must be 1..31"))
        << problems[0];
    EXPECT_TRUE(contains(problems[1], "module 3 node 32 (" + std::string(to_string(p)) +
                                          "): local node id must be 1..31"))
        << problems[1];
    EXPECT_TRUE(map.modules().empty());
    // The default map of module 1 (surface 33..63) cannot carry a pdop/qd module.
    EXPECT_EQ(map.add_module(1, NodeMap::default_pairs(1), p).size(), 31u);
    EXPECT_TRUE(map.add_module(0, NodeMap::default_pairs(0), p).empty());
  }
}

TEST(IdProfileNodeMap, ImageOverlapNamesBothOwnersAndTheCobId) {
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, {{5, 5}}, IdProfile::qd).empty());
  auto problems = map.add_module(2, {{5, 37}}, IdProfile::cia301);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_EQ(problems[0],
            "COB-ID 0x1A5: module 2 (cia301) local node 5 -> surface 37 TPDO1 collides with "
            "module 1 (qd) local node 5 -> surface 5 TPDO2 (11 COB-IDs collide in all)");
  EXPECT_EQ(map.modules().size(), 1u);
  // Nothing of the refused module was kept: surface 0x1A5 still routes to module 1.
  EXPECT_EQ(map.owner_of_surface_cob(0x1A5)->local_cob, 0x1A5);
  EXPECT_FALSE(map.owner_of_surface(37));

  // The other way round, and against pdop's t/c variants.
  NodeMap other;
  ASSERT_TRUE(other.add_module(0, {{40, 40}}).empty());
  auto pdop = other.add_module(1, {{2, 8}}, IdProfile::pdop);
  ASSERT_EQ(pdop.size(), 1u);
  EXPECT_TRUE(contains(pdop[0],
                       "COB-ID 0x1A8: module 1 (pdop) local node 2 -> surface 8 TPDO1 "
                       "t=0 c=1 collides with module 0 (cia301) local node 40 -> "
                       "surface 40 TPDO1"))
      << pdop[0];
  // Away from the images of the others, qd, pdop and cia301 modules live side by side.
  NodeMap mixed;
  EXPECT_TRUE(mixed.add_module(0, {{1, 1}, {2, 2}}, IdProfile::qd).empty());
  EXPECT_TRUE(mixed.add_module(1, {{1, 3}}, IdProfile::pdop).empty());
  EXPECT_TRUE(mixed.add_module(2, {{1, 100}, {127, 127}}, IdProfile::cia301).empty());
  EXPECT_FALSE(mixed.add_module(3, {{1, 33}}, IdProfile::cia301).empty());  // qd node 1 slot 1
  EXPECT_FALSE(mixed.add_module(3, {{1, 67}}, IdProfile::cia301).empty());  // pdop node 3 t=1
}

}  // namespace
}  // namespace canbridge::bridge
