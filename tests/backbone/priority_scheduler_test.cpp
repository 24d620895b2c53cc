#include "backbone/priority_scheduler.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace canbridge::backbone {
namespace {

using Scheduler = PriorityScheduler<std::string>;
using Push = SchedulerPush;

// Two lanes as the frame outbox uses them: one that refuses when full, one that drops its oldest.
constexpr std::size_t kRefusing = 0;
constexpr std::size_t kDropping = 1;

Scheduler two_lanes(std::size_t refusing_max, std::size_t dropping_max) {
  return Scheduler({{refusing_max, Overflow::refuse}, {dropping_max, Overflow::drop_oldest}});
}

std::vector<std::string> drain(Scheduler& scheduler) {
  std::vector<std::string> out;
  while (auto popped = scheduler.pop()) out.push_back(popped->item);
  return out;
}

TEST(PriorityScheduler, LowerPriorityLeavesFirstAndEqualPrioritiesInArrivalOrder) {
  Scheduler scheduler = two_lanes(16, 16);
  EXPECT_TRUE(scheduler.empty());
  EXPECT_FALSE(scheduler.pop());
  // Every item in a stream of its own: only priority and arrival decide.
  EXPECT_EQ(scheduler.push(kRefusing, 1, 0x300, false, "c1"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 2, 0x100, false, "a1"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 3, 0x300, false, "c2"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 4, 0x200, false, "b1"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 5, 0x100, false, "a2"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 6, 0x300, false, "c3"), Push::queued);
  EXPECT_EQ(scheduler.size(), 6u);
  EXPECT_EQ(scheduler.stream_count(), 6u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"a1", "a2", "b1", "c1", "c2", "c3"}));
  EXPECT_TRUE(scheduler.empty());
  EXPECT_EQ(scheduler.counters(kRefusing).popped, 6u);
  EXPECT_EQ(scheduler.stream_count(), 0u);
}

TEST(PriorityScheduler, ManyItemsOfOnePriorityStayStrictlyFifo) {
  Scheduler scheduler = two_lanes(1000, 1000);
  for (int i = 0; i < 1000; ++i) {
    // Alternating streams of one priority: arrival order across them too.
    ASSERT_EQ(
        scheduler.push(kDropping, static_cast<std::uint64_t>(i % 3), 7, false, std::to_string(i)),
        Push::queued);
  }
  for (int i = 0; i < 1000; ++i) EXPECT_EQ(scheduler.pop()->item, std::to_string(i));
}

TEST(PriorityScheduler, AStreamNeverReordersWhileOtherStreamsOvertakeIt) {
  // One node's boot-up (0x705) and then its EMCY (0x085), another node's EMCY (0x083) between
  // them: the bus would send 0x083 first, and 0x085 must not overtake 0x705 of its own stream.
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kRefusing, /*node 5*/ 5, 0x705, false, "boot-up 5");
  scheduler.push(kRefusing, /*node 3*/ 3, 0x083, false, "emcy 3");
  scheduler.push(kRefusing, 5, 0x085, false, "emcy 5");
  scheduler.push(kRefusing, 3, 0x583, false, "sdo 3");
  scheduler.push(kRefusing, /*node 1*/ 1, 0x600, false, "sdo 1");
  EXPECT_EQ(scheduler.stream_count(), 3u);
  // Heads: 0x083 < 0x583 (stream 3 again) < 0x600 < 0x705; then stream 5's next head 0x085.
  EXPECT_EQ(drain(scheduler),
            (std::vector<std::string>{"emcy 3", "sdo 3", "sdo 1", "boot-up 5", "emcy 5"}));
}

TEST(PriorityScheduler, AStreamsNextHeadCompetesWithItsOwnPriority) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kRefusing, 1, 0x500, false, "a-slow");
  scheduler.push(kRefusing, 1, 0x010, false, "a-urgent");
  scheduler.push(kRefusing, 2, 0x100, false, "b");
  scheduler.push(kRefusing, 3, 0x400, false, "c");
  // a-slow blocks a-urgent until it leaves; then a-urgent outranks what is left.
  ASSERT_EQ(scheduler.pop()->item, "b");
  ASSERT_EQ(scheduler.pop()->item, "c");
  ASSERT_EQ(scheduler.pop()->item, "a-slow");
  scheduler.push(kRefusing, 4, 0x020, false, "d");
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"a-urgent", "d"}));
}

TEST(PriorityScheduler, LanesInterleaveByPriorityThenArrival) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kDropping, 1, 0x200, true, "p200");
  scheduler.push(kRefusing, 1, 0x200, false, "r200");  // same key, another lane: another stream
  scheduler.push(kRefusing, 2, 0x080, false, "r080");
  scheduler.push(kDropping, 2, 0x080, false, "p080");
  scheduler.push(kDropping, 3, 0x700, true, "p700");
  std::vector<std::pair<std::string, std::size_t>> popped;
  while (auto item = scheduler.pop()) popped.emplace_back(item->item, item->lane);
  const std::vector<std::pair<std::string, std::size_t>> expected{{"r080", kRefusing},
                                                                  {"p080", kDropping},
                                                                  {"p200", kDropping},
                                                                  {"r200", kRefusing},
                                                                  {"p700", kDropping}};
  EXPECT_EQ(popped, expected);
}

TEST(PriorityScheduler, PoppedCarriesItsPriorityAndLane) {
  Scheduler scheduler = two_lanes(4, 4);
  scheduler.push(kDropping, 0x181, 0x181, true, "pdo");
  auto popped = scheduler.pop();
  ASSERT_TRUE(popped);
  EXPECT_EQ(popped->item, "pdo");
  EXPECT_EQ(popped->lane, kDropping);
  EXPECT_EQ(popped->priority, 0x181u);
}

TEST(PriorityScheduler, ConflationKeepsThePositionAndTakesTheNewestValue) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kDropping, /*key=*/100, 5, true, "x-old");
  scheduler.push(kDropping, /*key=*/200, 5, true, "y");
  scheduler.push(kRefusing, 100, 5, false, "r");
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, true, "x-mid"), Push::conflated);
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, true, "x-new"), Push::conflated);
  EXPECT_EQ(scheduler.size(), 3u);
  EXPECT_EQ(scheduler.lane_size(kDropping), 2u);
  EXPECT_EQ(scheduler.counters(kDropping).conflated, 2u);
  EXPECT_EQ(scheduler.counters(kDropping).queued, 2u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"x-new", "y", "r"}));
}

TEST(PriorityScheduler, ConflationKeepsTheQueuedPriority) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kDropping, 1, 9, true, "a");
  scheduler.push(kDropping, 2, 5, true, "b");
  EXPECT_EQ(scheduler.push(kDropping, 1, 1, true, "a2"), Push::conflated);
  auto first = scheduler.pop();
  EXPECT_EQ(first->item, "b");
  auto second = scheduler.pop();
  EXPECT_EQ(second->item, "a2");
  EXPECT_EQ(second->priority, 9u);
}

TEST(PriorityScheduler, AfterPopTheSameKeyIsQueuedAfresh) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kDropping, 100, 5, true, "x1");
  scheduler.push(kDropping, 200, 5, true, "y1");
  ASSERT_EQ(scheduler.pop()->item, "x1");
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, true, "x2"), Push::queued);  // not into the popped
  EXPECT_EQ(scheduler.counters(kDropping).conflated, 0u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"y1", "x2"}));
}

TEST(PriorityScheduler, UnconflatedPushNeitherConflatesNorIsConflatedInto) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kDropping, 100, 5, true, "conflatable");
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, false, "plain"), Push::queued);
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, true, "newest"), Push::queued);
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, true, "newer"), Push::conflated);
  // One stream: its items leave in their order; only the newest replaceable one took a value.
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"conflatable", "plain", "newer"}));
}

TEST(PriorityScheduler, AFullRefusingLaneRefusesAndCounts) {
  Scheduler scheduler = two_lanes(2, 16);
  EXPECT_EQ(scheduler.push(kRefusing, 1, 1, false, "r1"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 2, 1, false, "r2"), Push::queued);
  EXPECT_EQ(scheduler.push(kRefusing, 3, 0, false, "r3"), Push::refused);
  EXPECT_EQ(scheduler.push(kRefusing, 1, 0, false, "r3"), Push::refused);
  EXPECT_EQ(scheduler.counters(kRefusing).refused, 2u);
  EXPECT_EQ(scheduler.counters(kRefusing).queued, 2u);
  // The other lane has its own room.
  EXPECT_EQ(scheduler.push(kDropping, 7, 1, true, "p"), Push::queued);
  EXPECT_EQ(scheduler.lane_size(kRefusing), 2u);
  EXPECT_EQ(scheduler.lane_size(kDropping), 1u);
  ASSERT_EQ(scheduler.pop()->item, "r1");
  EXPECT_EQ(scheduler.push(kRefusing, 3, 0, false, "r3"), Push::queued);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"r3", "r2", "p"}));
}

TEST(PriorityScheduler, AFullDroppingLaneDropsItsOldestAndCounts) {
  Scheduler scheduler = two_lanes(16, 3);
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, false, "1"), Push::queued);
  EXPECT_EQ(scheduler.push(kDropping, 200, 1, false, "2"), Push::queued);
  EXPECT_EQ(scheduler.push(kDropping, 100, 5, false, "3"), Push::queued);
  // Full: "1" is the oldest, though "2" would leave first.
  EXPECT_EQ(scheduler.push(kDropping, 300, 9, false, "4"), Push::displaced);
  EXPECT_EQ(scheduler.push(kDropping, 200, 1, false, "5"), Push::displaced);  // drops "2"
  EXPECT_EQ(scheduler.counters(kDropping).dropped_oldest, 2u);
  EXPECT_EQ(scheduler.counters(kDropping).queued, 5u);
  EXPECT_EQ(scheduler.lane_size(kDropping), 3u);
  // The refusing lane is untouched by the other lane's overflow.
  EXPECT_EQ(scheduler.push(kRefusing, 1, 9, false, "r"), Push::queued);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"5", "3", "4", "r"}));
}

TEST(PriorityScheduler, DroppingTheOldestEmptiesItsStreamCleanly) {
  // The dropped item is the only one of the stream the new item joins: it starts the stream anew.
  Scheduler scheduler = two_lanes(16, 2);
  scheduler.push(kDropping, 1, 4, false, "a");
  scheduler.push(kDropping, 2, 2, false, "b");
  EXPECT_EQ(scheduler.push(kDropping, 1, 4, false, "a2"), Push::displaced);
  EXPECT_EQ(scheduler.stream_count(), 2u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"b", "a2"}));
}

TEST(PriorityScheduler, AFullLaneStillConflates) {
  Scheduler scheduler = two_lanes(16, 2);
  scheduler.push(kDropping, 1, 5, true, "a");
  scheduler.push(kDropping, 2, 5, true, "b");
  EXPECT_EQ(scheduler.push(kDropping, 1, 5, true, "a2"), Push::conflated);
  EXPECT_EQ(scheduler.counters(kDropping).dropped_oldest, 0u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"a2", "b"}));
}

TEST(PriorityScheduler, EraseIfRemovesItemsWhereverTheyWaitAndKeepsTheRest) {
  Scheduler scheduler = two_lanes(16, 16);
  scheduler.push(kRefusing, 1, 0x600, false, "x-head");  // a head: its stream moves on
  scheduler.push(kRefusing, 1, 0x000, false, "keep-1");
  scheduler.push(kRefusing, 1, 0x600, false, "x-middle");
  scheduler.push(kRefusing, 1, 0x100, false, "keep-2");
  scheduler.push(kRefusing, 1, 0x600, false, "x-tail");
  scheduler.push(kRefusing, 2, 0x050, false, "x-alone");  // its stream empties
  scheduler.push(kDropping, 3, 0x080, true, "keep-3");
  EXPECT_EQ(scheduler.erase_if([](const std::string& s) { return s.starts_with("x-"); }), 4u);
  EXPECT_EQ(scheduler.size(), 3u);
  EXPECT_EQ(scheduler.lane_size(kRefusing), 2u);
  EXPECT_EQ(scheduler.stream_count(), 2u);
  // Stream 1's head is now keep-1 (0x000), ahead of keep-3 (0x080); the tail was relinked.
  scheduler.push(kRefusing, 1, 0x000, false, "keep-4");
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"keep-1", "keep-3", "keep-2", "keep-4"}));
}

TEST(PriorityScheduler, FrontShowsWhatPopWouldReturnWithoutPopping) {
  Scheduler scheduler = two_lanes(16, 16);
  EXPECT_FALSE(scheduler.front());
  scheduler.push(kDropping, 1, 3, true, "p");
  scheduler.push(kRefusing, 1, 2, false, "r");
  auto front = scheduler.front();
  ASSERT_TRUE(front);
  EXPECT_EQ(*front->item, "r");
  EXPECT_EQ(front->lane, kRefusing);
  EXPECT_EQ(front->priority, 2u);
  EXPECT_EQ(scheduler.size(), 2u);
  EXPECT_EQ(scheduler.front()->item, front->item);  // peeking twice changes nothing
  scheduler.push(kDropping, 1, 3, true, "p2");
  ASSERT_EQ(scheduler.pop()->item, "r");
  EXPECT_EQ(*scheduler.front()->item, "p2");
  EXPECT_EQ(scheduler.front()->lane, kDropping);
}

TEST(PriorityScheduler, WorksWithMoveOnlyItems) {
  PriorityScheduler<std::unique_ptr<int>> scheduler(
      {{4, Overflow::refuse}, {4, Overflow::drop_oldest}});
  scheduler.push(0, 1, 2, false, std::make_unique<int>(2));
  scheduler.push(1, 9, 1, true, std::make_unique<int>(1));
  scheduler.push(1, 9, 1, true, std::make_unique<int>(10));
  EXPECT_EQ(*scheduler.pop()->item, 10);
  EXPECT_EQ(*scheduler.pop()->item, 2);
}

TEST(PriorityScheduler, RejectsLimitsBeyondItsSlotIndices) {
  using Small = PriorityScheduler<int>;
  EXPECT_THROW(Small({{0xFFFFFFFFu, Overflow::refuse}}), std::invalid_argument);
  EXPECT_THROW(Small({{0x80000000u, Overflow::refuse}, {0x80000000u, Overflow::drop_oldest}}),
               std::invalid_argument);
}

TEST(PriorityScheduler, ZeroLimitsQueueNothing) {
  Scheduler scheduler = two_lanes(0, 0);
  EXPECT_EQ(scheduler.push(kRefusing, 1, 1, false, "r"), Push::refused);
  EXPECT_EQ(scheduler.push(kDropping, 1, 1, true, "p"), Push::refused);
  EXPECT_EQ(scheduler.push(kDropping, 1, 1, false, "p"), Push::refused);
  EXPECT_EQ(scheduler.counters(kDropping).refused, 2u);
  EXPECT_TRUE(scheduler.empty());
}

TEST(PriorityScheduler, StreamHeadIsTheOldestQueuedItemOfThatStreamInThatLane) {
  Scheduler scheduler = two_lanes(8, 8);
  EXPECT_EQ(scheduler.stream_head(kDropping, 5), nullptr);
  scheduler.push(kDropping, 5, 2, false, "a");
  scheduler.push(kDropping, 5, 2, false, "b");
  scheduler.push(kRefusing, 5, 1, false, "same key, other lane");
  scheduler.push(kDropping, 6, 0, false, "other stream");
  ASSERT_NE(scheduler.stream_head(kDropping, 5), nullptr);
  EXPECT_EQ(*scheduler.stream_head(kDropping, 5), "a");
  EXPECT_EQ(*scheduler.stream_head(kRefusing, 5), "same key, other lane");
  EXPECT_EQ(*scheduler.stream_head(kDropping, 6), "other stream");
  EXPECT_EQ(scheduler.stream_head(kDropping, 7), nullptr);
  // A conflation changes the newest item, not the head.
  scheduler.push(kDropping, 5, 2, true, "c");
  scheduler.push(kDropping, 5, 2, true, "d");
  EXPECT_EQ(*scheduler.stream_head(kDropping, 5), "a");
  EXPECT_EQ(drain(scheduler),
            (std::vector<std::string>{"other stream", "same key, other lane", "a", "b", "d"}));
  EXPECT_EQ(scheduler.stream_head(kDropping, 5), nullptr);
}

TEST(PriorityScheduler, StorageGrowsWithTheBacklogNotTheBoundsAndIsGivenBackWhenDrained) {
  PriorityScheduler<std::uint64_t> scheduler(
      {{1u << 22, Overflow::refuse}, {1u << 22, Overflow::drop_oldest}});
  EXPECT_EQ(scheduler.storage_items(), 0u);
  // 20,000 items in 5,000 streams: each lane's stream index doubles many times on the way.
  constexpr std::uint64_t kItems = 20000;
  constexpr std::uint64_t kStreams = 5000;
  for (std::uint64_t i = 0; i < kItems; ++i) {
    ASSERT_EQ(scheduler.push(i % 2, i % kStreams, static_cast<std::uint32_t>(i % 7), false, i),
              Push::queued);
  }
  EXPECT_EQ(scheduler.stream_count(), kStreams);
  EXPECT_GE(scheduler.storage_items(), kItems);
  for (std::uint64_t s = 0; s < kStreams; ++s) {
    ASSERT_NE(scheduler.stream_head(s % 2, s), nullptr);
    EXPECT_EQ(*scheduler.stream_head(s % 2, s), s);  // each stream's first item, found again
  }
  // Every stream leaves in its own order after the rehashes.
  std::vector<std::uint64_t> last(kStreams, kItems);
  std::uint64_t popped = 0;
  while (auto p = scheduler.pop()) {
    const std::uint64_t stream = p->item % kStreams;
    if (last[stream] != kItems) {
      ASSERT_GT(p->item, last[stream]);
    }
    last[stream] = p->item;
    ++popped;
  }
  EXPECT_EQ(popped, kItems);
  // Drained after a large backlog: the storage is given back.
  EXPECT_EQ(scheduler.storage_items(), 0u);
  // A small backlog keeps its storage: a steady trickle does not allocate on every wake.
  for (std::uint64_t i = 0; i < 10; ++i) scheduler.push(1, i, 0, false, i);
  while (scheduler.pop()) {
  }
  EXPECT_GE(scheduler.storage_items(), 10u);
  EXPECT_LE(scheduler.storage_items(), Scheduler::kKeptWhenIdle);
}

// ---------------------------------------------------------------------------------------------
// Random operations against an obviously correct model: a vector searched linearly.

struct ModelItem {
  std::size_t lane;
  std::uint64_t stream;
  std::uint32_t priority;
  std::uint64_t arrival;
  bool replaceable;
  std::uint64_t value;
};

class Model {
 public:
  explicit Model(std::vector<SchedulerLane> lanes) : lanes_(std::move(lanes)) {}

  Push push(std::size_t lane, std::uint64_t stream, std::uint32_t priority, bool replace,
            std::uint64_t value) {
    ModelItem* newest = nullptr;
    for (ModelItem& item : items_) {
      if (item.lane == lane && item.stream == stream) newest = &item;  // items_ in arrival order
    }
    if (replace && newest && newest->replaceable) {
      newest->value = value;
      return Push::conflated;
    }
    Push result = Push::queued;
    const auto in_lane = [&](const ModelItem& i) { return i.lane == lane; };
    if (static_cast<std::size_t>(std::count_if(items_.begin(), items_.end(), in_lane)) >=
        lanes_[lane].max_items) {
      const auto oldest = std::find_if(items_.begin(), items_.end(), in_lane);
      if (lanes_[lane].overflow == Overflow::refuse || oldest == items_.end()) {
        return Push::refused;
      }
      items_.erase(oldest);
      result = Push::displaced;
    }
    items_.push_back({lane, stream, priority, next_arrival_++, replace, value});
    return result;
  }

  // Among the items that are first of their stream: lowest priority, then earliest arrival.
  std::optional<ModelItem> pop() {
    std::optional<std::size_t> best;
    for (std::size_t i = 0; i < items_.size(); ++i) {
      bool head = true;
      for (std::size_t j = 0; j < i; ++j) {
        if (items_[j].lane == items_[i].lane && items_[j].stream == items_[i].stream) head = false;
      }
      if (!head) continue;
      if (!best || items_[i].priority < items_[*best].priority) best = i;
    }
    if (!best) return std::nullopt;
    ModelItem item = items_[*best];
    items_.erase(items_.begin() + static_cast<std::ptrdiff_t>(*best));
    return item;
  }

  std::size_t erase_if(std::uint64_t divisor, std::uint64_t remainder) {
    return static_cast<std::size_t>(
        std::erase_if(items_, [&](const ModelItem& i) { return i.value % divisor == remainder; }));
  }

  std::size_t size() const { return items_.size(); }
  std::size_t lane_size(std::size_t lane) const {
    return static_cast<std::size_t>(std::count_if(
        items_.begin(), items_.end(), [&](const ModelItem& i) { return i.lane == lane; }));
  }

 private:
  std::vector<SchedulerLane> lanes_;
  std::uint64_t next_arrival_ = 0;
  std::vector<ModelItem> items_;  // in arrival order
};

class PrioritySchedulerProperty : public ::testing::TestWithParam<std::uint32_t> {};

TEST_P(PrioritySchedulerProperty, BehavesLikeTheReferenceModel) {
  std::mt19937 rng(GetParam());
  // Small limits and few priorities and streams, so that ties, blocked heads, conflation and full
  // lanes are common.
  const std::vector<SchedulerLane> lanes = {{1 + rng() % 40, Overflow::refuse},
                                            {rng() % 40, Overflow::drop_oldest},
                                            {1 + rng() % 10, Overflow::drop_oldest}};
  PriorityScheduler<std::uint64_t> scheduler(lanes);
  Model model(lanes);
  std::uint64_t next_value = 0;
  std::uint64_t pushes = 0;
  std::uint64_t pops = 0;
  std::uint64_t erased = 0;
  // Phases that push more than they pop alternate with phases that drain.
  for (int op = 0; op < 20000; ++op) {
    const bool filling = (op / 500) % 2 == 0;
    if (rng() % 100 == 0) {
      // A withdrawal: items wherever they wait, heads or not, some streams emptied.
      const std::uint64_t divisor = 2 + rng() % 4;
      const std::uint64_t remainder = rng() % divisor;
      const std::size_t removed =
          scheduler.erase_if([&](std::uint64_t v) { return v % divisor == remainder; });
      ASSERT_EQ(removed, model.erase_if(divisor, remainder)) << "op " << op;
      erased += removed;
    } else if (rng() % 100 < (filling ? 70u : 30u)) {
      const std::size_t lane = rng() % lanes.size();
      const std::uint32_t priority = rng() % 8;
      const std::uint64_t stream = rng() % 12;
      const bool replace = rng() % 4 != 0;
      const std::uint64_t value = next_value++;
      ASSERT_EQ(scheduler.push(lane, stream, priority, replace, value),
                model.push(lane, stream, priority, replace, value))
          << "op " << op;
      ++pushes;
    } else {
      const auto front = scheduler.front();
      const auto expected = model.pop();
      const auto actual = scheduler.pop();
      ASSERT_EQ(actual.has_value(), expected.has_value()) << "op " << op;
      ASSERT_EQ(front.has_value(), expected.has_value()) << "op " << op;
      if (expected) {
        ASSERT_EQ(actual->item, expected->value) << "op " << op;
        ASSERT_EQ(actual->lane, expected->lane) << "op " << op;
        ASSERT_EQ(actual->priority, expected->priority) << "op " << op;
        ASSERT_EQ(front->priority, expected->priority) << "op " << op;
        ASSERT_EQ(front->lane, expected->lane) << "op " << op;
      }
      ++pops;
    }
    ASSERT_EQ(scheduler.size(), model.size()) << "op " << op;
    for (std::size_t l = 0; l < lanes.size(); ++l) {
      ASSERT_EQ(scheduler.lane_size(l), model.lane_size(l)) << "op " << op;
      ASSERT_LE(scheduler.lane_size(l), lanes[l].max_items);
    }
    ASSERT_LE(scheduler.stream_count(), scheduler.size());
  }
  std::uint64_t counted = 0;
  std::uint64_t queued = 0;
  std::uint64_t left = 0;
  for (std::size_t l = 0; l < lanes.size(); ++l) {
    const auto& c = scheduler.counters(l);
    counted += c.queued + c.conflated + c.refused;
    queued += c.queued;
    left += c.popped + c.dropped_oldest;
  }
  EXPECT_EQ(counted, pushes);
  EXPECT_EQ(queued, left + erased + scheduler.size());
  EXPECT_GT(pops, 0u);
  EXPECT_GT(erased, 0u);
}

INSTANTIATE_TEST_SUITE_P(Seeds, PrioritySchedulerProperty,
                         ::testing::Values(1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u, 99u, 12345u));

TEST(PriorityScheduler, StreamIndexSurvivesHeavyChurnOfManyKeys) {
  // Many distinct streams through a small lane: the index is erased from and re-filled all the
  // time, which is where an open-addressing table breaks if deletion loses entries.
  const std::vector<SchedulerLane> lanes = {{1, Overflow::refuse}, {64, Overflow::drop_oldest}};
  PriorityScheduler<std::uint64_t> scheduler(lanes);
  Model model(lanes);
  std::mt19937_64 rng(7);
  for (int op = 0; op < 200000; ++op) {
    if (rng() % 2 == 0) {
      const std::uint64_t key = rng() % 300;
      const std::uint32_t priority = static_cast<std::uint32_t>(key % 5);
      const bool replace = key % 3 != 0;
      ASSERT_EQ(scheduler.push(1, key, priority, replace, static_cast<std::uint64_t>(op)),
                model.push(1, key, priority, replace, static_cast<std::uint64_t>(op)))
          << "op " << op;
    } else {
      const auto expected = model.pop();
      const auto actual = scheduler.pop();
      ASSERT_EQ(actual.has_value(), expected.has_value());
      if (expected) {
        ASSERT_EQ(actual->item, expected->value) << "op " << op;
      }
    }
    ASSERT_LE(scheduler.stream_count(), scheduler.size());
  }
}

TEST(PriorityScheduler, MemoryStaysBoundedUnderSustainedOverload) {
  constexpr std::size_t kMaxRefusing = 256;
  constexpr std::size_t kMaxDropping = 512;
  Scheduler::Lane refusing{kMaxRefusing, Overflow::refuse};
  Scheduler::Lane dropping{kMaxDropping, Overflow::drop_oldest};
  PriorityScheduler<std::uint64_t> scheduler({refusing, dropping});
  std::mt19937 rng(3);
  std::uint64_t refused = 0;
  std::uint64_t displaced = 0;
  for (std::uint64_t i = 0; i < 1'000'000; ++i) {
    const std::uint32_t priority = rng() % 2048;
    Push result;
    switch (rng() % 4) {
      case 0:
        result = scheduler.push(0, rng() % 128, priority, false, i);
        break;
      case 1:
        result = scheduler.push(1, 0, priority, false, i);
        break;
      default:
        result = scheduler.push(1, rng() % 100000, priority, true, i);
        break;
    }
    refused += result == Push::refused;
    displaced += result == Push::displaced;
    if (i % 3 == 0) scheduler.pop();  // the link drains a third of what arrives
    ASSERT_LE(scheduler.lane_size(0), kMaxRefusing);
    ASSERT_LE(scheduler.lane_size(1), kMaxDropping);
  }
  // Both lanes sit at their bound (the last operation was a pop).
  EXPECT_GE(scheduler.lane_size(0), kMaxRefusing - 1);
  EXPECT_GE(scheduler.lane_size(1), kMaxDropping - 1);
  EXPECT_EQ(scheduler.counters(0).refused, refused);
  EXPECT_EQ(scheduler.counters(1).dropped_oldest, displaced);
  EXPECT_GT(refused, 100000u);
  EXPECT_GT(displaced, 100000u);
}

}  // namespace
}  // namespace canbridge::backbone
