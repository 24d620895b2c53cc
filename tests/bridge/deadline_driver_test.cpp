// The role's one deadline driver: due cores get the same `now` (virtual clock through fire_due),
// the loop sleeps until the earliest deadline on a real short timer, and reschedule() wakes it
// when input moved a deadline earlier. No test sleeps: each runs the io_context until a core
// was called, with a deadline far beyond the timers involved.
#include "bridge/deadline_driver.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <chrono>
#include <optional>
#include <string>
#include <vector>

#include "coro/spawn_owned.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using TimePoint = DeadlineDriver::TimePoint;

const TimePoint kDriverStart = TimePoint{} + 1000s;

// A core with one deadline; records the `now` of each call and clears its deadline.
struct FakeCore {
  std::optional<TimePoint> deadline;
  std::vector<TimePoint> calls;
  void add_to(DeadlineDriver& driver, std::string name) {
    driver.add(
        std::move(name), [this] { return deadline; },
        [this](TimePoint now) {
          calls.push_back(now);
          deadline.reset();
        });
  }
};

TEST(DeadlineDriver, CallsOnlyTheDueCoresWithTheSameNowAndReportsTheEarliestLeft) {
  boost::asio::io_context io;
  DeadlineDriver driver(io.get_executor());
  FakeCore a, b, idle;
  a.deadline = kDriverStart + 10ms;
  b.deadline = kDriverStart + 20ms;
  a.add_to(driver, "a");
  b.add_to(driver, "b");
  idle.add_to(driver, "idle");
  EXPECT_EQ(driver.earliest(), kDriverStart + 10ms);

  EXPECT_EQ(driver.fire_due(kDriverStart + 5ms), kDriverStart + 10ms);  // nothing due yet
  EXPECT_TRUE(a.calls.empty());

  EXPECT_EQ(driver.fire_due(kDriverStart + 15ms), kDriverStart + 20ms);
  EXPECT_EQ(a.calls, std::vector<TimePoint>{kDriverStart + 15ms});
  EXPECT_TRUE(b.calls.empty());

  a.deadline = kDriverStart + 30ms;  // both due at once: one call each, the same now
  EXPECT_EQ(driver.fire_due(kDriverStart + 40ms), std::nullopt);
  EXPECT_EQ(a.calls.back(), kDriverStart + 40ms);
  EXPECT_EQ(b.calls, std::vector<TimePoint>{kDriverStart + 40ms});
  EXPECT_TRUE(idle.calls.empty());
  EXPECT_EQ(driver.counters().deadlines, 3u);
}

TEST(DeadlineDriver, ADeadlineExactlyAtNowIsDue) {
  boost::asio::io_context io;
  DeadlineDriver driver(io.get_executor());
  FakeCore a;
  a.deadline = kDriverStart;
  a.add_to(driver, "a");
  driver.fire_due(kDriverStart - 1ns);
  EXPECT_TRUE(a.calls.empty());
  driver.fire_due(kDriverStart);
  EXPECT_EQ(a.calls.size(), 1u);
}

// The loop on a real timer, `now` from an injected clock: the core sees the clock's value.
TEST(DeadlineDriver, WakesAtTheEarliestDeadlineWithTheInjectedNow) {
  boost::asio::io_context io;
  std::vector<TimePoint> clock_reads;
  DeadlineDriver driver(io.get_executor(), [&clock_reads] {
    clock_reads.push_back(DeadlineDriver::Clock::now());
    return clock_reads.back();
  });
  FakeCore soon, later;
  const TimePoint start = DeadlineDriver::Clock::now();
  soon.deadline = start + 20ms;
  later.deadline = start + 1h;
  soon.add_to(driver, "soon");
  later.add_to(driver, "later");
  std::optional<std::string> ended;
  coro::spawn_owned(io, driver.run(), [&ended](const std::string& why) { ended = why; });

  ASSERT_TRUE(test::run_until(
      io, [&] { return !soon.calls.empty(); }, 5000ms));
  EXPECT_GE(soon.calls[0], start + 20ms);  // never early
  ASSERT_FALSE(clock_reads.empty());
  EXPECT_EQ(soon.calls[0], clock_reads.back());
  EXPECT_TRUE(later.calls.empty());
  ASSERT_TRUE(test::run_until(
      io, [&] { return driver.armed_until() == start + 1h; }, 5000ms));

  driver.stop();
  ASSERT_TRUE(test::run_until(
      io, [&] { return ended.has_value(); }, 5000ms));
  EXPECT_EQ(*ended, "");  // returned, threw nothing
}

// Input moves a core's deadline from an hour away to 10 ms: reschedule() wakes the sleeping
// loop, which re-arms; without it the core would wait the hour.
TEST(DeadlineDriver, RescheduleWakesTheLoopForAnEarlierDeadline) {
  boost::asio::io_context io;
  DeadlineDriver driver(io.get_executor());
  FakeCore core;
  const TimePoint start = DeadlineDriver::Clock::now();
  core.deadline = start + 1h;
  core.add_to(driver, "core");
  std::optional<std::string> ended;
  coro::spawn_owned(io, driver.run(), [&ended](const std::string& why) { ended = why; });
  ASSERT_TRUE(test::run_until(
      io, [&] { return driver.armed_until() == start + 1h; }, 5000ms));

  core.deadline = start + 2h;  // later: nothing to do, no wake-up
  driver.reschedule();
  EXPECT_EQ(driver.counters().rearms, 0u);

  core.deadline = DeadlineDriver::Clock::now() + 10ms;
  driver.reschedule();
  driver.reschedule();  // a second call before the loop re-armed costs nothing more
  EXPECT_EQ(driver.counters().rearms, 1u);
  ASSERT_TRUE(test::run_until(
      io, [&] { return !core.calls.empty(); }, 5000ms));
  EXPECT_GE(core.calls[0], start + 10ms);
  EXPECT_EQ(driver.counters().wakeups, 1u);
  driver.stop();
  ASSERT_TRUE(test::run_until(
      io, [&] { return ended.has_value(); }, 5000ms));
}

TEST(DeadlineDriver, SleepsWithoutWakingWhenNoCoreHasADeadline) {
  boost::asio::io_context io;
  DeadlineDriver driver(io.get_executor());
  FakeCore core;
  core.add_to(driver, "core");
  std::optional<std::string> ended;
  coro::spawn_owned(io, driver.run(), [&ended](const std::string& why) { ended = why; });
  io.run_for(30ms);
  EXPECT_EQ(driver.armed_until(), TimePoint::max());
  EXPECT_EQ(driver.counters().wakeups, 0u);
  EXPECT_FALSE(ended.has_value());
  driver.stop();
  ASSERT_TRUE(test::run_until(
      io, [&] { return ended.has_value(); }, 5000ms));
}

}  // namespace
}  // namespace canbridge::bridge
