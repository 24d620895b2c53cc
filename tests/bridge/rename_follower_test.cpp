// The live node map (issue 14): NodeMap::move and its problems, and follow_rename applying the
// node table's events: a planned move confirmed by the boot-up, a rename on the module bus to an
// unmapped id, refusals, and the translator using the moved pair in both directions.
#include "routing/rename_follower.hpp"

#include <gtest/gtest.h>

#include "canopen/nmt_node_id.hpp"
#include "routing/cob_id_translator.hpp"
#include "tests/bridge/translator_probe.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Kind = NodeEvent::Kind;
using Change = RenameFollowed::Change;
namespace nid = canopen::nmt_node_id;

const NodeTable::TimePoint kFollowerStart = NodeTable::TimePoint{} + 1000s;

// The canopen system test's layout: a cia301 module and a pdop module (surface ids 1..31).
struct Live {
  Live() {
    EXPECT_TRUE(map.add_module(1, {{10, 42}, {11, 43}}).empty());
    EXPECT_TRUE(map.add_module(2, {{1, 3}, {2, 4}, {3, 7}}, IdProfile::pdop).empty());
    table.add_module(IdProfile::cia301);
    table.add_module(IdProfile::pdop);
  }
  // A surface frame through the translator; what reached module `m`'s bus is fed to the table
  // as the gateway does.
  std::vector<std::pair<std::size_t, Frame>> from_surface(const Frame& f, NodeTable::TimePoint at) {
    auto routed = testing::routes(translator, f);
    for (const auto& [m, local] : routed) {
      if (local.id == 0) table.on_nmt_to_bus(m, local, at, events);
    }
    follow();
    return routed;
  }
  // A frame read on module `m`'s bus: node table, follow, then translate (the gateway's order).
  std::optional<Frame> from_bus(std::size_t m, const Frame& f, NodeTable::TimePoint at) {
    table.on_bus_frame(m, f, at, events);
    if (f.id == 0) table.on_nmt_to_bus(m, f, at, events);
    follow();
    return translator.to_surface(m, f);
  }
  void tick(NodeTable::TimePoint at) {
    table.tick(at, events);
    follow();
  }
  void follow() {
    for (; followed < events.size(); ++followed) {
      results.push_back(follow_rename(map, events[followed]));
    }
  }
  NodeMap map;
  CobIdTranslator translator{map};
  NodeTable table;
  std::vector<NodeEvent> events;
  std::vector<RenameFollowed> results;
  std::size_t followed = 0;
};

TEST(NodeMapMove, MovesThePairAndItsImageAndFreesTheOldId) {
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());  // local n -> n + 32
  EXPECT_EQ(map.move_problem(0, 5, 5, 100), std::nullopt);
  ASSERT_TRUE(map.move(0, 5, 5, 100));
  EXPECT_EQ(map.surface_of(0, 5), 100);
  EXPECT_EQ(map.owner_of_surface(100)->local, 5);
  EXPECT_FALSE(map.owner_of_surface(37));  // freed
  EXPECT_EQ(map.surface_cob_of(0, 0x185), 0x1E4);
  EXPECT_EQ(map.owner_of_surface_cob(0x1E4)->local_cob, 0x185);
  EXPECT_FALSE(map.owner_of_surface_cob(0x1A5));
  // The freed id can be taken again, by another local id of the module.
  ASSERT_TRUE(map.move(0, 6, 40, 37));
  EXPECT_EQ(map.surface_of(0, 6), 0);
  EXPECT_EQ(map.surface_of(0, 40), 37);
  EXPECT_FALSE(map.owner_of_surface(38));
  EXPECT_EQ(map.surface_cob_of(0, 0x600 + 40), 0x600 + 37);
  EXPECT_EQ(map.surface_cob_of(0, 0x606), 0);
}

TEST(NodeMapMove, ProblemsNameWhatIsInTheWay) {
  NodeMap map;
  // Surface ids off the pdop node's low five bits (docs/id-profiles.md).
  ASSERT_TRUE(map.add_module(1, {{5, 37}, {6, 38}}).empty());
  ASSERT_TRUE(map.add_module(2, {{1, 3}}, IdProfile::pdop).empty());
  const auto problem = [&](std::size_t m, NodeId from, NodeId to, NodeId surface) {
    return map.move_problem(m, from, to, surface).value_or("");
  };
  EXPECT_NE(problem(0, 5, 5, 38).find("already owned by module 1 node 6"), std::string::npos);
  EXPECT_NE(problem(0, 5, 5, 3).find("already owned by module 2 node 1"), std::string::npos);
  EXPECT_NE(problem(0, 5, 6, 100).find("local node id 6 is mapped to surface 38"),
            std::string::npos);
  EXPECT_NE(problem(0, 5, 5, 0).find("outside 1..127"), std::string::npos);
  EXPECT_NE(problem(1, 1, 1, 32).find("outside 1..31"), std::string::npos);
  EXPECT_NE(problem(1, 1, 40, 5).find("local node id 40 is outside 1..31"), std::string::npos);
  // 0x1E3: TPDO1 of surface 99 on the cia301 surface, the pdop node's TPDO1 t=1 c=1.
  EXPECT_NE(problem(0, 5, 5, 99).find("collides with module 2 (pdop) local node 1"),
            std::string::npos)
      << problem(0, 5, 5, 99);
  EXPECT_FALSE(map.move(0, 5, 5, 99));
  EXPECT_EQ(map.surface_of(0, 5), 37);  // unchanged
  EXPECT_EQ(problem(0, 5, 5, 37), "");  // its own id: fine (a reset)
}

// The whole path of a surface master's `E0 cc nn` to a free surface id.
TEST(RenameFollower, AFreeSurfaceIdIsTakenWhenTheBootUpConfirmsIt) {
  Live live;
  live.from_bus(1, Frame::standard(0x701, {0x05}),
                kFollowerStart);  // pdop local 1 (surface 3) beats
  auto sent = live.from_surface(Frame::standard(0x000, {0xE0, 3, 9}), kFollowerStart + 10ms);
  ASSERT_EQ(sent.size(), 1u);
  EXPECT_EQ(sent[0].second, nid::encode(nid::ChangeNodeId{1, 1}));
  // Until the boot-up, the node is where it was.
  EXPECT_EQ(live.map.surface_of(1, 1), 3);
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x181, {1}), kFollowerStart + 11ms)->id, 0x183u);
  // The confirming boot-up already crosses under the new id.
  const auto boot = live.from_bus(1, Frame::standard(0x701, {0x00}), kFollowerStart + 50ms);
  ASSERT_TRUE(boot);
  EXPECT_EQ(boot->id, 0x709u);
  ASSERT_EQ(live.events.back().kind, Kind::renamed);
  EXPECT_EQ(live.events.back().local, 1);
  EXPECT_EQ(live.events.back().previous_local, 1);
  EXPECT_EQ(live.events.back().previous_surface, 3);
  EXPECT_EQ(live.results.back().change, Change::moved);
  // Both directions use the new pair; the old surface id is free.
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x1A1, {1}), kFollowerStart + 60ms)->id, 0x1A9u);
  const auto sdo =
      live.from_surface(Frame::standard(0x609, {0x40, 0x18, 0x10, 0x04}), kFollowerStart + 70ms);
  ASSERT_EQ(sdo.size(), 1u);
  EXPECT_EQ(sdo[0].second.id, 0x601u);
  EXPECT_TRUE(live.from_surface(Frame::standard(0x603, {0x40}), kFollowerStart + 70ms).empty());
  EXPECT_FALSE(live.map.owner_of_surface(3));
  // And back: 3 is free again.
  ASSERT_EQ(live.from_surface(Frame::standard(0x000, {0xE0, 9, 3}), kFollowerStart + 1s).size(),
            1u);
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x701, {0x00}), kFollowerStart + 1050ms)->id, 0x703u);
  EXPECT_EQ(live.map.surface_of(1, 1), 3);
  EXPECT_FALSE(live.map.owner_of_surface(9));
}

TEST(RenameFollower, AnUnconfirmedCommandMovesNothing) {
  Live live;
  live.from_bus(1, Frame::standard(0x701, {0x05}), kFollowerStart);
  ASSERT_EQ(live.from_surface(Frame::standard(0x000, {0xE0, 3, 9}), kFollowerStart).size(), 1u);
  EXPECT_EQ(live.map.planned_move(1, 1), 9);
  live.tick(kFollowerStart + 2s);  // the confirm window
  ASSERT_FALSE(live.events.empty());
  EXPECT_EQ(live.events.back().kind, Kind::rename_unconfirmed);
  EXPECT_EQ(live.map.planned_move(1, 1), 0);
  // A later boot-up (a power cycle) is a plain boot-up: the node stays on 3.
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x701, {0x00}), kFollowerStart + 5s)->id, 0x703u);
  EXPECT_EQ(live.events.back().kind, Kind::booted);
  EXPECT_EQ(live.map.surface_of(1, 1), 3);
}

TEST(RenameFollower, ATargetTakenBeforeTheBootUpIsRefusedAndTheNodeStays) {
  Live live;
  ASSERT_EQ(live.from_surface(Frame::standard(0x000, {0xE0, 3, 9}), kFollowerStart).size(), 1u);
  ASSERT_EQ(live.from_surface(Frame::standard(0x000, {0xE0, 4, 9}), kFollowerStart).size(), 1u);
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x702, {0x00}), kFollowerStart + 10ms)->id, 0x709u);
  EXPECT_EQ(live.results.back().change, Change::moved);
  // Local 1 confirms second: 9 is local 2's now. Refused, reported, local 1 keeps surface 3.
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x701, {0x00}), kFollowerStart + 20ms)->id, 0x703u);
  EXPECT_EQ(live.results.back().change, Change::refused);
  EXPECT_NE(live.results.back().reason.find("already owned by module 2 node 2"), std::string::npos)
      << live.results.back().reason;
  EXPECT_EQ(live.events.back().kind, Kind::booted);
}

// A master on the module bus renames with local ids: to an id the module maps, the map has it;
// to one it does not map, the node keeps its surface id there instead of vanishing.
TEST(RenameFollower, ARenameOnTheModuleBusKeepsTheNodeOnTheSurface) {
  Live live;
  live.from_bus(1, Frame::standard(0x701, {0x05}), kFollowerStart);
  EXPECT_FALSE(
      live.from_bus(1, nid::encode(nid::ChangeNodeId{1, 20}), kFollowerStart));  // not forwarded
  const auto boot = live.from_bus(1, Frame::standard(0x714, {0x00}), kFollowerStart + 30ms);
  ASSERT_TRUE(boot);
  EXPECT_EQ(boot->id, 0x703u);
  ASSERT_EQ(live.events.back().kind, Kind::renamed);
  EXPECT_EQ(live.events.back().previous_surface, 3);
  EXPECT_EQ(live.map.surface_of(1, 20), 3);
  EXPECT_EQ(live.map.surface_of(1, 1), 0);
  const auto sdo =
      live.from_surface(Frame::standard(0x603, {0x40, 0x18, 0x10, 0x04}), kFollowerStart + 40ms);
  ASSERT_EQ(sdo.size(), 1u);
  EXPECT_EQ(sdo[0].second.id, 0x614u);
  // To a mapped id (3 -> surface 7): nothing moves, the configured pair is used.
  live.from_bus(1, nid::encode(nid::ChangeNodeId{20, 3}), kFollowerStart + 1s);
  EXPECT_EQ(live.from_bus(1, Frame::standard(0x703, {0x00}), kFollowerStart + 1010ms)->id, 0x707u);
  EXPECT_EQ(live.results.back().change, Change::none);
  EXPECT_EQ(live.events.back().previous_surface, 3);
  EXPECT_EQ(live.map.surface_of(1, 20), 3);  // the pair stays; no node answers there now
  // An unmapped node renamed to an unmapped id has no surface id to keep: refused, reported.
  live.from_bus(1, nid::encode(nid::ChangeNodeId{25, 26}), kFollowerStart + 2s);
  EXPECT_FALSE(live.from_bus(1, Frame::standard(0x71A, {0x00}), kFollowerStart + 2010ms));
  EXPECT_EQ(live.results.back().change, Change::refused);
}

}  // namespace
}  // namespace canbridge::bridge
