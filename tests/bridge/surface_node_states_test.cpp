// The surface's view of its gateways' nodes: every node event kind, renames moving a node, a
// gateway's nodes counted lost while its link is down and forgotten when it restarts, and events
// it cannot use ignored.
#include "bridge/surface_node_states.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <set>
#include <tuple>
#include <vector>

namespace canbridge::bridge {

namespace {

constexpr std::uint32_t kNmtOperational = 0x05;
constexpr std::uint32_t kNmtStopped = 0x04;
constexpr std::uint32_t kNmtPreOperational = 0x7F;

v1::NodeEvent event(v1::NodeEvent::Kind kind, std::uint32_t module, std::uint32_t local,
                    std::uint32_t state = kNmtPreOperational) {
  v1::NodeEvent e;
  e.set_kind(kind);
  e.set_module_id(module);
  e.set_local_node(local);
  e.set_surface_node(local + 32 * module);
  e.set_nmt_state(state);
  return e;
}

v1::NodeEvent renamed(std::uint32_t module, std::uint32_t from, std::uint32_t to) {
  v1::NodeEvent e = event(v1::NodeEvent::RENAMED, module, to);
  e.set_previous_local_node(from);
  e.set_previous_surface_node(from + 32 * module);
  return e;
}

// A summary as (op, pre-op, stopped, loader, lost): compared and printed by GoogleTest as is.
using Counts =
    std::tuple<std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t>;
Counts counts(std::uint64_t op, std::uint64_t pre_op, std::uint64_t stopped, std::uint64_t loader,
              std::uint64_t lost) {
  return {op, pre_op, stopped, loader, lost};
}

class SurfaceNodeStatesTest : public ::testing::Test {
 protected:
  Counts summary() const {
    const NodeSummary n =
        states.summary([this](SurfaceNodeStates::GatewayId g) { return !down.contains(g); });
    return {n.operational, n.pre_operational, n.stopped, n.in_loader, n.lost};
  }
  SurfaceNodeStates states;
  std::set<SurfaceNodeStates::GatewayId> down;  // gateways whose link is down
};

TEST_F(SurfaceNodeStatesTest, NothingKnownCountsNothing) {
  EXPECT_EQ(summary(), counts(0, 0, 0, 0, 0));
  EXPECT_EQ(states.summary([](SurfaceNodeStates::GatewayId) { return true; }).total(), 0u);
}

TEST_F(SurfaceNodeStatesTest, ABootedNodeIsPreOperationalInTheStateItReports) {
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::BOOTED, 1, 5, kNmtPreOperational)));
  EXPECT_EQ(summary(), counts(0, 1, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, ADiscoveredNodeCountsInItsHeartbeatsState) {
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational)));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 6, kNmtStopped)));
  EXPECT_EQ(summary(), counts(1, 0, 1, 0, 0));
}

// A node the gateway heard only by its SDO answers (heartbeat off, booted before the gateway):
// counted apart, never as pre-operational (its 0xFF mark must not lose its top bit as a toggle).
TEST_F(SurfaceNodeStatesTest, ANodeInAStateNothingToldCountsUnknown) {
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, 0xFF)));
  const NodeSummary n = states.summary([](SurfaceNodeStates::GatewayId) { return true; });
  EXPECT_EQ(n.unknown, 1u);
  EXPECT_EQ(n.total(), 1u);
  EXPECT_EQ(summary(), counts(0, 0, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, AStateChangeMovesTheNodeBetweenCounts) {
  states.apply(0, event(v1::NodeEvent::BOOTED, 1, 5));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::STATE_CHANGED, 1, 5, kNmtOperational)));
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 0));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::STATE_CHANGED, 1, 5, kNmtStopped)));
  EXPECT_EQ(summary(), counts(0, 0, 1, 0, 0));
  EXPECT_EQ(states.size(), 1u);
}

TEST_F(SurfaceNodeStatesTest, ALostNodeCountsLostUntilItRecovers) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::LOST, 1, 5, kNmtOperational)));
  EXPECT_EQ(summary(), counts(0, 0, 0, 0, 1));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::RECOVERED, 1, 5, kNmtStopped)));
  EXPECT_EQ(summary(), counts(0, 0, 1, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, ALossOfANodeNeverSeenStillCountsIt) {
  // The surface missed its first event (it started after the node was discovered).
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::LOST, 1, 9, kNmtOperational)));
  EXPECT_EQ(summary(), counts(0, 0, 0, 0, 1));
}

TEST_F(SurfaceNodeStatesTest, ANodeInItsLoaderCountsInLoaderUntilItsApplicationBoots) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::LOADER_BOOTED, 1, 5, 0x00)));
  EXPECT_EQ(summary(), counts(0, 0, 0, 1, 0));
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::BOOTED, 1, 5, kNmtPreOperational)));
  EXPECT_EQ(summary(), counts(0, 1, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, InLoaderAsTheGatewayReportsItCountsInLoader) {
  v1::NodeEvent e = event(v1::NodeEvent::STATE_CHANGED, 1, 5, 0x00);
  e.set_in_loader(true);
  states.apply(0, e);
  EXPECT_EQ(summary(), counts(0, 0, 0, 1, 0));
}

// What the surface lists for a gateway that is down: its nodes by module and local id, with the
// surface id, boot count and loader state of their last events, and nothing of other gateways.
TEST_F(SurfaceNodeStatesTest, EachNodeOfOneGatewayIsListedWithItsLastEvent) {
  v1::NodeEvent booted = event(v1::NodeEvent::BOOTED, 2, 3);
  booted.set_boot_count(4);
  states.apply(0, booted);
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 7, kNmtOperational));
  states.apply(0, event(v1::NodeEvent::LOADER_BOOTED, 2, 1, 0x00));
  states.apply(0, event(v1::NodeEvent::LOST, 1, 7));
  states.apply(1, event(v1::NodeEvent::DISCOVERED, 1, 9, kNmtOperational));
  std::vector<std::tuple<std::uint32_t, std::uint32_t, std::uint32_t, std::uint32_t, bool, bool>>
      listed;  // module, local, surface id, boot count, lost, in loader
  states.for_each_node(
      0, [&](std::uint32_t module, std::uint32_t local, const SurfaceNodeStates::Node& n) {
        listed.emplace_back(module, local, n.surface_node, n.boot_count, n.lost, n.in_loader);
      });
  using Row = decltype(listed)::value_type;
  EXPECT_EQ(listed, (decltype(listed){Row{1, 7, 39, 0, true, false}, Row{2, 1, 65, 0, false, true},
                                      Row{2, 3, 67, 4, false, false}}));
}

TEST_F(SurfaceNodeStatesTest, ARenameMovesTheNodeFromItsPreviousIdToTheNewOne) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 6, kNmtOperational));
  EXPECT_TRUE(states.apply(0, renamed(1, 5, 9)));
  // The renamed node booted on its new id (pre-operational); the old id holds nothing.
  EXPECT_EQ(summary(), counts(1, 1, 0, 0, 0));
  EXPECT_EQ(states.size(), 2u);
  // A later loss of the old id would be an event for a node that no longer exists there: only
  // the new id's events count it.
  EXPECT_TRUE(states.apply(0, event(v1::NodeEvent::LOST, 1, 9)));
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 1));
}

TEST_F(SurfaceNodeStatesTest, ARenameOfTheSameModuleIdOnAnotherGatewayMovesNothingThere) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(1, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(0, renamed(1, 5, 9));
  EXPECT_EQ(summary(), counts(1, 1, 0, 0, 0));
  EXPECT_EQ(states.size(), 2u);
}

TEST_F(SurfaceNodeStatesTest, ARenameFromAnUnknownIdAddsTheNodeAndLeavesTheOthers) {
  // A by-serial command whose node the gateway could not name: previous id 0.
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  EXPECT_TRUE(states.apply(0, renamed(1, 0, 9)));
  EXPECT_EQ(summary(), counts(1, 1, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, ARenameToANewSurfaceIdOnTheSameLocalIdKeepsOneNode) {
  // A surface master's move to a free surface id: the local id stays, the surface id changes.
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  v1::NodeEvent e = renamed(1, 5, 5);
  e.set_previous_surface_node(37);
  e.set_surface_node(40);
  EXPECT_TRUE(states.apply(0, e));
  EXPECT_EQ(summary(), counts(0, 1, 0, 0, 0));
  EXPECT_EQ(states.size(), 1u);
}

TEST_F(SurfaceNodeStatesTest, AnUnconfirmedRenameMovesNothing) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  v1::NodeEvent e = event(v1::NodeEvent::RENAME_UNCONFIRMED, 1, 9, 0x00);
  e.set_previous_local_node(5);
  EXPECT_FALSE(states.apply(0, e));
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 0));
  EXPECT_EQ(states.size(), 1u);
}

TEST_F(SurfaceNodeStatesTest, UnknownKindsAndIdsOutOfRangeAreIgnored) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  EXPECT_FALSE(states.apply(0, event(v1::NodeEvent::KIND_UNSPECIFIED, 1, 5, kNmtStopped)));
  EXPECT_FALSE(states.apply(0, event(static_cast<v1::NodeEvent::Kind>(42), 1, 5, kNmtStopped)));
  EXPECT_FALSE(states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 0, kNmtStopped)));
  EXPECT_FALSE(states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 128, kNmtStopped)));
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 0));
  EXPECT_EQ(states.size(), 1u);
}

TEST_F(SurfaceNodeStatesTest, AGatewayWhoseLinkIsDownCountsItsNodesLostAndBackWhenItReturns) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(0, event(v1::NodeEvent::BOOTED, 1, 6));
  states.apply(1, event(v1::NodeEvent::DISCOVERED, 2, 5, kNmtOperational));
  down.insert(0);
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 2));
  down.clear();  // the same process: its stream resumes, the states are still its nodes'
  EXPECT_EQ(summary(), counts(2, 1, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, ARestartedGatewaysNodesAreForgottenAndOthersKept) {
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 3, 7, kNmtStopped));
  states.apply(1, event(v1::NodeEvent::DISCOVERED, 2, 5, kNmtOperational));
  states.apply(2, event(v1::NodeEvent::BOOTED, 4, 5));
  states.forget(0);
  EXPECT_EQ(summary(), counts(1, 1, 0, 0, 0));
  EXPECT_EQ(states.size(), 2u);
  // The new process reports its nodes again as it hears them.
  states.apply(0, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtPreOperational));
  EXPECT_EQ(summary(), counts(1, 2, 0, 0, 0));
}

TEST_F(SurfaceNodeStatesTest, TheLastGatewayIdCanBeForgotten) {
  constexpr auto kLast = UINT32_MAX;
  states.apply(kLast, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.apply(kLast - 1, event(v1::NodeEvent::DISCOVERED, 1, 5, kNmtOperational));
  states.forget(kLast);
  EXPECT_EQ(states.size(), 1u);
  EXPECT_EQ(summary(), counts(1, 0, 0, 0, 0));
}

}  // namespace
}  // namespace canbridge::bridge
