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

std::vector<std::string> drain(Scheduler& scheduler) {
  std::vector<std::string> out;
  while (auto popped = scheduler.pop()) out.push_back(popped->item);
  return out;
}

TEST(PriorityScheduler, LowerPriorityLeavesFirstAndEqualPrioritiesInArrivalOrder) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  EXPECT_TRUE(scheduler.empty());
  EXPECT_FALSE(scheduler.pop());
  EXPECT_EQ(scheduler.push_reliable(0x300, "c1"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0x100, "a1"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0x300, "c2"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0x200, "b1"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0x100, "a2"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0x300, "c3"), Push::queued);
  EXPECT_EQ(scheduler.size(), 6u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"a1", "a2", "b1", "c1", "c2", "c3"}));
  EXPECT_TRUE(scheduler.empty());
  EXPECT_EQ(scheduler.counters().popped, 6u);
}

TEST(PriorityScheduler, ManyItemsOfOnePriorityStayStrictlyFifo) {
  Scheduler scheduler({.max_reliable = 1000, .max_process = 1000});
  for (int i = 0; i < 1000; ++i) {
    ASSERT_EQ(scheduler.push_process(7, 0, /*conflate=*/false, std::to_string(i)), Push::queued);
  }
  for (int i = 0; i < 1000; ++i) EXPECT_EQ(scheduler.pop()->item, std::to_string(i));
}

TEST(PriorityScheduler, ClassesInterleaveByPriorityThenArrival) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  scheduler.push_process(0x200, 1, true, "p200");
  scheduler.push_reliable(0x200, "r200");
  scheduler.push_reliable(0x080, "r080");
  scheduler.push_process(0x080, 2, false, "p080");
  scheduler.push_process(0x700, 3, true, "p700");
  std::vector<std::pair<std::string, bool>> popped;
  while (auto item = scheduler.pop()) popped.emplace_back(item->item, item->reliable);
  const std::vector<std::pair<std::string, bool>> expected{
      {"r080", true}, {"p080", false}, {"p200", false}, {"r200", true}, {"p700", false}};
  EXPECT_EQ(popped, expected);
}

TEST(PriorityScheduler, PoppedCarriesItsPriorityAndClass) {
  Scheduler scheduler({.max_reliable = 4, .max_process = 4});
  scheduler.push_process(0x181, 0x181, true, "pdo");
  auto popped = scheduler.pop();
  ASSERT_TRUE(popped);
  EXPECT_EQ(popped->item, "pdo");
  EXPECT_FALSE(popped->reliable);
  EXPECT_EQ(popped->priority, 0x181u);
}

TEST(PriorityScheduler, ConflationKeepsThePositionAndTakesTheNewestValue) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  scheduler.push_process(5, /*key=*/100, true, "x-old");
  scheduler.push_process(5, /*key=*/200, true, "y");
  scheduler.push_reliable(5, "r");
  EXPECT_EQ(scheduler.push_process(5, 100, true, "x-mid"), Push::conflated);
  EXPECT_EQ(scheduler.push_process(5, 100, true, "x-new"), Push::conflated);
  EXPECT_EQ(scheduler.size(), 3u);
  EXPECT_EQ(scheduler.process_size(), 2u);
  EXPECT_EQ(scheduler.conflation_index_size(), 2u);
  EXPECT_EQ(scheduler.counters().conflated, 2u);
  EXPECT_EQ(scheduler.counters().process_queued, 2u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"x-new", "y", "r"}));
  EXPECT_EQ(scheduler.conflation_index_size(), 0u);
}

TEST(PriorityScheduler, ConflationKeepsTheQueuedPriority) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  scheduler.push_process(9, 1, true, "a");
  scheduler.push_process(5, 2, true, "b");
  EXPECT_EQ(scheduler.push_process(1, 1, true, "a2"), Push::conflated);
  auto first = scheduler.pop();
  EXPECT_EQ(first->item, "b");
  auto second = scheduler.pop();
  EXPECT_EQ(second->item, "a2");
  EXPECT_EQ(second->priority, 9u);
}

TEST(PriorityScheduler, AfterPopTheSameKeyIsQueuedAfresh) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  scheduler.push_process(5, 100, true, "x1");
  scheduler.push_process(5, 200, true, "y1");
  ASSERT_EQ(scheduler.pop()->item, "x1");
  EXPECT_EQ(scheduler.push_process(5, 100, true, "x2"), Push::queued);  // not into the popped one
  EXPECT_EQ(scheduler.counters().conflated, 0u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"y1", "x2"}));
}

TEST(PriorityScheduler, WithoutConflationProcessItemsAreFifoAndDroppedWhenFull) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 3});
  EXPECT_EQ(scheduler.push_process(5, 100, false, "1"), Push::queued);
  EXPECT_EQ(scheduler.push_process(5, 100, false, "2"), Push::queued);
  EXPECT_EQ(scheduler.push_process(5, 100, false, "3"), Push::queued);
  EXPECT_EQ(scheduler.push_process(5, 100, false, "4"), Push::refused);
  EXPECT_EQ(scheduler.push_process(1, 999, false, "5"), Push::refused);
  EXPECT_EQ(scheduler.counters().process_dropped, 2u);
  EXPECT_EQ(scheduler.counters().conflated, 0u);
  EXPECT_EQ(scheduler.conflation_index_size(), 0u);
  // Reliable items have their own room.
  EXPECT_EQ(scheduler.push_reliable(9, "r"), Push::queued);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"1", "2", "3", "r"}));
}

TEST(PriorityScheduler, UnconflatedPushNeitherConflatesNorIsConflatedInto) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  scheduler.push_process(5, 100, true, "conflatable");
  EXPECT_EQ(scheduler.push_process(5, 100, false, "plain"), Push::queued);
  EXPECT_EQ(scheduler.push_process(5, 100, true, "newest"), Push::conflated);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"newest", "plain"}));
}

TEST(PriorityScheduler, FullProcessQueueStillConflatesButDropsNewKeys) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 2});
  scheduler.push_process(5, 1, true, "a");
  scheduler.push_process(5, 2, true, "b");
  EXPECT_EQ(scheduler.push_process(5, 3, true, "c"), Push::refused);
  EXPECT_EQ(scheduler.push_process(5, 1, true, "a2"), Push::conflated);
  EXPECT_EQ(scheduler.counters().process_dropped, 1u);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"a2", "b"}));
}

TEST(PriorityScheduler, ReliableIsRefusedWhenFullAndCounted) {
  Scheduler scheduler({.max_reliable = 2, .max_process = 16});
  EXPECT_EQ(scheduler.push_reliable(1, "r1"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(1, "r2"), Push::queued);
  EXPECT_EQ(scheduler.push_reliable(0, "r3"), Push::refused);
  EXPECT_EQ(scheduler.counters().reliable_refused, 1u);
  EXPECT_EQ(scheduler.counters().reliable_queued, 2u);
  // Process items have their own room.
  EXPECT_EQ(scheduler.push_process(1, 7, true, "p"), Push::queued);
  EXPECT_EQ(scheduler.reliable_size(), 2u);
  EXPECT_EQ(scheduler.process_size(), 1u);
  ASSERT_EQ(scheduler.pop()->item, "r1");
  EXPECT_EQ(scheduler.push_reliable(0, "r3"), Push::queued);
  EXPECT_EQ(drain(scheduler), (std::vector<std::string>{"r3", "r2", "p"}));
}

TEST(PriorityScheduler, FrontShowsWhatPopWouldReturnWithoutPopping) {
  Scheduler scheduler({.max_reliable = 16, .max_process = 16});
  EXPECT_FALSE(scheduler.front());
  scheduler.push_process(3, 1, true, "p");
  scheduler.push_reliable(2, "r");
  auto front = scheduler.front();
  ASSERT_TRUE(front);
  EXPECT_EQ(*front->item, "r");
  EXPECT_TRUE(front->reliable);
  EXPECT_EQ(front->priority, 2u);
  EXPECT_EQ(scheduler.size(), 2u);
  EXPECT_EQ(scheduler.front()->item, front->item);  // peeking twice changes nothing
  scheduler.push_process(3, 1, true, "p2");
  ASSERT_EQ(scheduler.pop()->item, "r");
  EXPECT_EQ(*scheduler.front()->item, "p2");
  EXPECT_FALSE(scheduler.front()->reliable);
}

TEST(PriorityScheduler, WorksWithMoveOnlyItems) {
  PriorityScheduler<std::unique_ptr<int>> scheduler({.max_reliable = 4, .max_process = 4});
  scheduler.push_reliable(2, std::make_unique<int>(2));
  scheduler.push_process(1, 9, true, std::make_unique<int>(1));
  scheduler.push_process(1, 9, true, std::make_unique<int>(10));
  EXPECT_EQ(*scheduler.pop()->item, 10);
  EXPECT_EQ(*scheduler.pop()->item, 2);
}

TEST(PriorityScheduler, RejectsLimitsBeyondItsSlotIndices) {
  using Small = PriorityScheduler<int>;
  EXPECT_THROW(Small({.max_reliable = 0xFFFFFFFFu, .max_process = 0}), std::invalid_argument);
  EXPECT_THROW(Small({.max_reliable = 0x80000000u, .max_process = 0x80000000u}),
               std::invalid_argument);
}

TEST(PriorityScheduler, ZeroLimitsQueueNothing) {
  Scheduler scheduler({.max_reliable = 0, .max_process = 0});
  EXPECT_EQ(scheduler.push_reliable(1, "r"), Push::refused);
  EXPECT_EQ(scheduler.push_process(1, 1, true, "p"), Push::refused);
  EXPECT_EQ(scheduler.push_process(1, 1, false, "p"), Push::refused);
  EXPECT_TRUE(scheduler.empty());
}

// ---------------------------------------------------------------------------------------------
// Random operations against an obviously correct model: a vector searched linearly.

struct ModelItem {
  std::uint32_t priority;
  std::uint64_t arrival;
  bool reliable;
  std::optional<std::uint64_t> conflation_key;
  std::uint64_t value;
};

class Model {
 public:
  Model(std::size_t max_reliable, std::size_t max_process)
      : max_reliable_(max_reliable), max_process_(max_process) {}

  Push push(std::uint32_t priority, bool reliable, std::uint64_t key, bool conflate,
            std::uint64_t value) {
    if (!reliable && conflate) {
      for (ModelItem& item : items_) {
        if (item.conflation_key == key) {
          item.value = value;
          return Push::conflated;
        }
      }
    }
    const std::size_t same_class = static_cast<std::size_t>(std::count_if(
        items_.begin(), items_.end(), [&](const ModelItem& i) { return i.reliable == reliable; }));
    if (same_class >= (reliable ? max_reliable_ : max_process_)) return Push::refused;
    items_.push_back({priority, next_arrival_++, reliable,
                      conflate && !reliable ? std::optional<std::uint64_t>(key) : std::nullopt,
                      value});
    return Push::queued;
  }

  std::optional<ModelItem> pop() {
    if (items_.empty()) return std::nullopt;
    auto first = std::min_element(items_.begin(), items_.end(), [](const auto& a, const auto& b) {
      return a.priority != b.priority ? a.priority < b.priority : a.arrival < b.arrival;
    });
    ModelItem item = *first;
    items_.erase(first);
    return item;
  }

  std::size_t size() const { return items_.size(); }

 private:
  std::size_t max_reliable_;
  std::size_t max_process_;
  std::uint64_t next_arrival_ = 0;
  std::vector<ModelItem> items_;
};

class PrioritySchedulerProperty : public ::testing::TestWithParam<std::uint32_t> {};

TEST_P(PrioritySchedulerProperty, BehavesLikeTheReferenceModel) {
  std::mt19937 rng(GetParam());
  // Small limits and few priorities and keys, so that ties, conflation and full queues are common.
  const std::size_t max_reliable = 1 + rng() % 40;
  const std::size_t max_process = rng() % 40;
  PriorityScheduler<std::uint64_t> scheduler(
      {.max_reliable = max_reliable, .max_process = max_process});
  Model model(max_reliable, max_process);
  std::uint64_t next_value = 0;
  std::uint64_t pushes = 0;
  std::uint64_t pops = 0;
  // Phases that push more than they pop alternate with phases that drain.
  for (int op = 0; op < 20000; ++op) {
    const bool filling = (op / 500) % 2 == 0;
    if (rng() % 100 < (filling ? 70u : 30u)) {
      const std::uint32_t priority = rng() % 8;
      const bool reliable = rng() % 3 == 0;
      const std::uint64_t key = rng() % 12;
      const bool conflate = rng() % 4 != 0;
      const std::uint64_t value = next_value++;
      const auto expected = model.push(priority, reliable, key, conflate, value);
      const auto actual = reliable ? scheduler.push_reliable(priority, value)
                                   : scheduler.push_process(priority, key, conflate, value);
      ASSERT_EQ(actual, expected) << "op " << op;
      ++pushes;
    } else {
      const auto front = scheduler.front();
      const auto expected = model.pop();
      const auto actual = scheduler.pop();
      ASSERT_EQ(actual.has_value(), expected.has_value()) << "op " << op;
      ASSERT_EQ(front.has_value(), expected.has_value()) << "op " << op;
      if (expected) {
        ASSERT_EQ(actual->item, expected->value) << "op " << op;
        ASSERT_EQ(actual->reliable, expected->reliable) << "op " << op;
        ASSERT_EQ(actual->priority, expected->priority) << "op " << op;
        ASSERT_EQ(front->priority, expected->priority) << "op " << op;
        ASSERT_EQ(front->reliable, expected->reliable) << "op " << op;
      }
      ++pops;
    }
    ASSERT_EQ(scheduler.size(), model.size()) << "op " << op;
    ASSERT_LE(scheduler.reliable_size(), max_reliable);
    ASSERT_LE(scheduler.process_size(), max_process);
    ASSERT_LE(scheduler.conflation_index_size(), scheduler.process_size());
  }
  const auto& counters = scheduler.counters();
  EXPECT_EQ(counters.reliable_queued + counters.reliable_refused + counters.process_queued +
                counters.conflated + counters.process_dropped,
            pushes);
  EXPECT_EQ(counters.reliable_queued + counters.process_queued, counters.popped + scheduler.size());
  EXPECT_GT(pops, 0u);
}

INSTANTIATE_TEST_SUITE_P(Seeds, PrioritySchedulerProperty,
                         ::testing::Values(1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u, 99u, 12345u));

TEST(PriorityScheduler, ConflationIndexSurvivesHeavyChurnOfManyKeys) {
  // Many distinct keys through a small queue: the index is erased from and re-filled all the
  // time, which is where an open-addressing table breaks if deletion loses entries.
  PriorityScheduler<std::uint64_t> scheduler({.max_reliable = 1, .max_process = 64});
  Model model(1, 64);
  std::mt19937_64 rng(7);
  for (int op = 0; op < 200000; ++op) {
    if (rng() % 2 == 0) {
      const std::uint64_t key = rng() % 300;
      const std::uint32_t priority = static_cast<std::uint32_t>(key % 5);
      ASSERT_EQ(scheduler.push_process(priority, key, true, static_cast<std::uint64_t>(op)),
                model.push(priority, false, key, true, static_cast<std::uint64_t>(op)))
          << "op " << op;
    } else {
      const auto expected = model.pop();
      const auto actual = scheduler.pop();
      ASSERT_EQ(actual.has_value(), expected.has_value());
      if (expected) {
        ASSERT_EQ(actual->item, expected->value) << "op " << op;
      }
    }
    ASSERT_EQ(scheduler.conflation_index_size(), scheduler.process_size());
  }
}

TEST(PriorityScheduler, MemoryStaysBoundedUnderSustainedOverload) {
  constexpr std::size_t kMaxReliable = 256;
  constexpr std::size_t kMaxProcess = 512;
  PriorityScheduler<std::uint64_t> scheduler(
      {.max_reliable = kMaxReliable, .max_process = kMaxProcess});
  std::mt19937 rng(3);
  std::uint64_t refused = 0;
  for (std::uint64_t i = 0; i < 1'000'000; ++i) {
    const std::uint32_t priority = rng() % 2048;
    Push result;
    switch (rng() % 4) {
      case 0:
        result = scheduler.push_reliable(priority, i);
        break;
      case 1:
        result = scheduler.push_process(priority, 0, false, i);
        break;
      default:
        result = scheduler.push_process(priority, rng() % 100000, true, i);
        break;
    }
    refused += result == Push::refused;
    if (i % 3 == 0) scheduler.pop();  // the link drains a third of what arrives
    ASSERT_LE(scheduler.reliable_size(), kMaxReliable);
    ASSERT_LE(scheduler.process_size(), kMaxProcess);
    ASSERT_LE(scheduler.conflation_index_size(), scheduler.process_size());
  }
  // Both queues sit at their bound (the last operation was a pop).
  EXPECT_GE(scheduler.reliable_size(), kMaxReliable - 1);
  EXPECT_GE(scheduler.process_size(), kMaxProcess - 1);
  const auto& counters = scheduler.counters();
  EXPECT_EQ(counters.reliable_refused + counters.process_dropped, refused);
  EXPECT_GT(counters.reliable_refused, 100000u);
  EXPECT_GT(counters.process_dropped, 100000u);
}

}  // namespace
}  // namespace canbridge::backbone
