// The gateway's node reports to the surface, on their own: events encoded with both ids, a
// snapshot of the table for a new surface process, and the bound that drops the oldest events
// but never a snapshot.
#include "bridge/node_report_queue.hpp"

#include <gtest/gtest.h>

#include <vector>

#include "bridge/gateway_claims.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
const NodeTable::TimePoint kHeardAt = NodeTable::TimePoint{} + 1000s;

class NodeReportQueueTest : public ::testing::Test {
 protected:
  NodeReportQueueTest() {
    EXPECT_TRUE(map.add_module(7, NodeMap::default_pairs(1)).empty());  // local n: surface 32 + n
    table.add_module(IdProfile::cia301);
  }
  // The events of the payload at the front, which is then popped.
  v1::NodeEvents take() {
    v1::Payload payload;
    std::string* front = queue.front();
    EXPECT_NE(front, nullptr);
    if (front == nullptr) return {};
    EXPECT_TRUE(payload.ParseFromString(*front));
    queue.pop();
    return payload.node_events();
  }
  // Node `local` heard on the bus: a boot-up, then a heartbeat in `state`.
  std::vector<NodeEvent> hear(NodeId local, std::uint8_t state, NodeTable::TimePoint at) {
    std::vector<NodeEvent> events;
    table.on_bus_frame(0, can::Frame::standard(0x700u + local, {0x00}), at, events);
    table.on_bus_frame(0, can::Frame::standard(0x700u + local, {state}), at, events);
    return events;
  }

  NodeMap map;
  NodeTable table;
  NodeReportQueue queue{map, table, {7}, 2};
};

TEST_F(NodeReportQueueTest, AnEventCarriesTheModuleBothIdsAndTheNodesState) {
  const std::vector<NodeEvent> events = hear(3, 0x05, kHeardAt);
  ASSERT_FALSE(events.empty());
  EXPECT_FALSE(queue.queue_events(events, ""));
  const v1::NodeEvents sent = take();
  ASSERT_EQ(sent.events_size(), static_cast<int>(events.size()));
  const v1::NodeEvent& last = sent.events(sent.events_size() - 1);
  EXPECT_EQ(last.module_id(), 7u);
  EXPECT_EQ(last.local_node(), 3u);
  EXPECT_EQ(last.surface_node(), 35u);
  EXPECT_EQ(last.nmt_state(), 0x05u);
  EXPECT_FALSE(sent.has_claims());
  EXPECT_EQ(queue.front(), nullptr);
  EXPECT_EQ(queue.counters().events, events.size());
}

TEST_F(NodeReportQueueTest, ARenameNamesThePreviousIdsAndNewClaimsRideAlong) {
  NodeEvent renamed;
  renamed.kind = NodeEvent::Kind::renamed;
  renamed.module_index = 0;
  renamed.local = 4;
  renamed.previous_local = 3;  // the previous surface id follows from the map
  GatewayClaims claims;
  claims.modules.push_back({7, {36}, {}});
  EXPECT_FALSE(queue.queue_events(std::vector{renamed}, encode_claims(claims)));
  const v1::NodeEvents sent = take();
  ASSERT_EQ(sent.events_size(), 1);
  EXPECT_EQ(sent.events(0).kind(), v1::NodeEvent::RENAMED);
  EXPECT_EQ(sent.events(0).previous_local_node(), 3u);
  EXPECT_EQ(sent.events(0).previous_surface_node(), 35u);
  ASSERT_TRUE(sent.has_claims());
  EXPECT_EQ(decode_claims(sent.claims().SerializeAsString()), claims);
}

TEST_F(NodeReportQueueTest, ASnapshotReportsEveryKnownNodeAndALostOneAsLost) {
  (void)hear(1, 0x05, kHeardAt);
  (void)hear(2, 0x7F, kHeardAt);
  std::vector<NodeEvent> ticked;
  table.tick(kHeardAt + 60s, ticked);  // both silent since: lost
  (void)hear(1, 0x05, kHeardAt + 61s);
  const NodeReportQueue::Snapshot s = queue.queue_snapshot();
  EXPECT_EQ(s.nodes, 2u);
  EXPECT_EQ(s.lost, 1u);
  EXPECT_FALSE(s.dropped);
  const v1::NodeEvents sent = take();
  ASSERT_EQ(sent.events_size(), 3);
  EXPECT_EQ(sent.events(0).kind(), v1::NodeEvent::DISCOVERED);
  EXPECT_EQ(sent.events(0).local_node(), 1u);
  EXPECT_EQ(sent.events(1).kind(), v1::NodeEvent::DISCOVERED);
  EXPECT_EQ(sent.events(1).local_node(), 2u);
  EXPECT_EQ(sent.events(1).nmt_state(), 0x7Fu);
  EXPECT_EQ(sent.events(2).kind(), v1::NodeEvent::LOST);
  EXPECT_EQ(sent.events(2).local_node(), 2u);
  // A second snapshot replaces the first while it waits: one per module, never two.
  (void)queue.queue_snapshot();
  (void)queue.queue_snapshot();
  EXPECT_EQ(queue.size(), 1u);
}

// The bound: a link down for hours queues at most max_payloads payloads
// of events, the oldest dropped first (counted); the snapshot stays, as nothing repeats it.
TEST_F(NodeReportQueueTest, TheBoundDropsTheOldestEventsAndNeverTheSnapshot) {
  (void)hear(1, 0x05, kHeardAt);
  (void)queue.queue_snapshot();
  const std::vector<NodeEvent> first = hear(2, 0x05, kHeardAt);
  const std::vector<NodeEvent> second = hear(3, 0x05, kHeardAt);
  const std::vector<NodeEvent> third = hear(4, 0x05, kHeardAt);
  EXPECT_FALSE(queue.queue_events(first, ""));  // snapshot + 1: the bound (2) is reached
  EXPECT_TRUE(queue.queue_events(second, ""));  // `first` goes
  EXPECT_TRUE(queue.queue_events(third, ""));   // `second` goes
  EXPECT_EQ(queue.counters().events_dropped, first.size() + second.size());
  EXPECT_EQ(take().events(0).kind(), v1::NodeEvent::DISCOVERED);  // the snapshot, still first
  EXPECT_EQ(take().events(0).local_node(), 4u);
  EXPECT_EQ(queue.front(), nullptr);
}

}  // namespace
}  // namespace canbridge::bridge
