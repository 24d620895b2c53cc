// GatewayNodeEvents on its own: a confirmed rename moves the node in the live map once, tells
// the owner which module moved and re-encodes the claims for the next report only; a refused
// set-node-id command becomes a RENAME_UNCONFIRMED event carrying the node's state.
#include "bridge/gateway_node_events.hpp"

#include <gtest/gtest.h>

#include "bridge/gateway_claims.hpp"
#include "routing/cob_id_translator.hpp"
#include "tests/bridge/translator_probe.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Kind = NodeEvent::Kind;

const NodeTable::TimePoint kStart = NodeTable::TimePoint{} + 1000s;

// A cia301 module and a pdop module, as the gateway holds them.
struct Nodes {
  Nodes() {
    EXPECT_TRUE(map.add_module(1, {{10, 42}, {11, 43}}).empty());
    EXPECT_TRUE(map.add_module(2, {{1, 3}, {2, 4}}, IdProfile::pdop).empty());
    table.add_module(IdProfile::cia301);
    table.add_module(IdProfile::pdop);
  }
  // What the gateway does with a frame of module `m`'s bus.
  void from_bus(std::size_t m, const Frame& f, NodeTable::TimePoint at) {
    table.on_bus_frame(m, f, at, events.sink());
    events.follow_renames();
  }
  void from_surface(const Frame& f, NodeTable::TimePoint at) {
    for (const auto& [m, local] : testing::routes(translator, f)) {
      if (local.id == 0) table.on_nmt_to_bus(m, local, at, events.sink());
    }
  }
  NodeMap map;
  CobIdTranslator translator{map};
  NodeTable table;
  std::vector<std::size_t> moved;
  GatewayNodeEvents events{"gw", map, {1, 2}, [this](std::size_t m) { moved.push_back(m); }};
};

TEST(GatewayNodeEvents, AConfirmedRenameMovesTheNodeOnceAndItsClaimsGoWithTheNextEventsOnly) {
  Nodes n;
  n.from_bus(1, Frame::standard(0x701, {0x05}), kStart);  // pdop local 1 (surface 3) beats
  n.from_surface(Frame::standard(0x000, {0xE0, 3, 9}), kStart + 10ms);
  const std::string claims_before = encode_claims(claims_of(n.map));
  ASSERT_FALSE(n.events.settle().has_value()) << "nothing moved yet";
  n.events.clear();

  n.from_bus(1, Frame::standard(0x701, {0x00}), kStart + 50ms);  // the confirming boot-up
  // Followed at the frame already, before the events are settled.
  EXPECT_EQ(n.map.surface_of(1, 1), 9);
  EXPECT_EQ(n.moved, std::vector<std::size_t>{1});
  ASSERT_FALSE(n.events.empty());
  EXPECT_EQ(n.events.events().back().kind, Kind::renamed);
  n.events.follow_renames();  // again: nothing is followed twice
  EXPECT_EQ(n.events.counters().nodes_moved, 1u);

  const std::optional<std::string> claims = n.events.settle();
  ASSERT_TRUE(claims.has_value());
  EXPECT_EQ(*claims, encode_claims(claims_of(n.map)));
  EXPECT_NE(*claims, claims_before);
  n.events.clear();
  EXPECT_TRUE(n.events.empty());

  n.from_bus(0, Frame::standard(0x70A, {0x05}), kStart + 1s);  // another node's first beat
  ASSERT_FALSE(n.events.empty());
  EXPECT_FALSE(n.events.settle().has_value()) << "the claims went with the rename already";
  EXPECT_EQ(n.moved.size(), 1u);
}

TEST(GatewayNodeEvents, ARefusedCommandToAKnownNodeIsReportedWithTheNodesState) {
  Nodes n;
  n.from_bus(0, Frame::standard(0x70A, {0x05}), kStart);  // local 10 operational
  n.events.clear();
  RenameRefusal refusal;
  refusal.node = NodeOwner{0, 10};
  refusal.surface = 42;
  refusal.next_surface = 3;
  refusal.reason = "surface id 3 is owned by module 2 node 1";
  n.events.on_rename_refused(refusal, n.table, kStart + 1s);
  ASSERT_EQ(n.events.events().size(), 1u);
  const NodeEvent& e = n.events.events().front();
  EXPECT_EQ(e.kind, Kind::rename_unconfirmed);
  EXPECT_EQ(e.module_index, 0u);
  EXPECT_EQ(e.local, 10);
  EXPECT_EQ(e.state, n.table.node(0, 10)->state);
  EXPECT_EQ(e.at, kStart + 1s);

  // By serial, to a node the map does not have: said, nothing to report.
  n.events.clear();
  n.events.on_rename_refused(RenameRefusal{std::nullopt, 0, 5, "no node has that serial"}, n.table,
                             kStart + 2s);
  EXPECT_TRUE(n.events.empty());
  EXPECT_EQ(n.map.surface_of(0, 10), 42);  // nothing moved
}

}  // namespace
}  // namespace canbridge::bridge
