// LowPriorityQueue: work on it gives way to the loop's other work, a bounded amount per pass, and
// nothing it holds outlives the loop.
#include "backbone/low_priority_executor.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/dispatch.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <chrono>
#include <functional>
#include <memory>
#include <string>

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;

// The longest run of 'L' in `trace` before its last 'E'.
std::size_t longest_low_run_while_busy(const std::string& trace) {
  const auto last_established = trace.rfind('E');
  std::size_t longest = 0;
  std::size_t run = 0;
  for (std::size_t i = 0; i < last_established && last_established != std::string::npos; ++i) {
    run = trace[i] == 'L' ? run + 1 : 0;
    longest = std::max(longest, run);
  }
  return longest;
}

// An established link's work: ready again every pass of the loop, `turns` times.
void keep_busy(asio::io_context& io, std::string& trace, int turns) {
  if (turns == 0) return;
  asio::post(io, [&io, &trace, turns] {
    trace += 'E';
    keep_busy(io, trace, turns - 1);
  });
}

TEST(LowPriorityQueue, AtMostPerPassHandlersRunBetweenTwoTurnsOfTheOtherWork) {
  asio::io_context io(1);
  auto queue = LowPriorityQueue::create(io.get_executor(), 2);
  std::string trace;
  // A flood's handshake steps, all ready at once, queued before the link's work.
  for (int i = 0; i < 20; ++i) asio::post(queue->executor(), [&trace] { trace += 'L'; });
  keep_busy(io, trace, 12);
  io.run();

  EXPECT_EQ(std::count(trace.begin(), trace.end(), 'L'), 20) << trace;
  EXPECT_EQ(std::count(trace.begin(), trace.end(), 'E'), 12) << trace;
  EXPECT_LE(longest_low_run_while_busy(trace), 2u) << trace;
  EXPECT_EQ(queue->counters().run, 20u);
  EXPECT_EQ(queue->counters().passes, 10u);
  EXPECT_EQ(queue->counters().deferred, 9u);
  EXPECT_EQ(queue->counters().queued_peak, 20u);
  EXPECT_EQ(queue->queued(), 0u);
}

TEST(LowPriorityQueue, WorkAlreadyReadyRunsBeforeWorkQueuedOnIt) {
  asio::io_context io(1);
  auto queue = LowPriorityQueue::create(io.get_executor(), 4);
  std::string trace;
  asio::post(io, [&trace] { trace += 'E'; });
  // dispatch() may run a function in place on an executor that allows it; this one never does.
  asio::dispatch(queue->executor(), [&trace] { trace += 'L'; });
  trace += '.';
  io.run();
  EXPECT_EQ(trace, ".EL");
}

TEST(LowPriorityQueue, ACoroutineSpawnedOnItResumesThroughTheQueue) {
  asio::io_context io(1);
  auto queue = LowPriorityQueue::create(io.get_executor(), 1);
  bool same_executor = false;
  bool done = false;
  asio::co_spawn(
      queue->executor(),
      [&]() -> asio::awaitable<void> {
        const auto executor = co_await asio::this_coro::executor;
        same_executor = executor == asio::any_io_executor(queue->executor());
        // A timer of the loop itself: its completion still comes back through the queue.
        asio::steady_timer timer(io, std::chrono::milliseconds(1));
        co_await timer.async_wait(asio::use_awaitable);
        done = true;
      },
      [](std::exception_ptr error) {
        if (error) std::rethrow_exception(error);
      });
  io.run();
  EXPECT_TRUE(same_executor);
  EXPECT_TRUE(done);
  // The start, the resumption after the timer, the completion handler.
  EXPECT_GE(queue->counters().run, 3u);
}

TEST(LowPriorityQueue, WorkLeftQueuedWhenTheLoopGoesIsDestroyedNotLeaked) {
  auto witness = std::make_shared<int>(0);
  std::weak_ptr<int> watched = witness;
  std::weak_ptr<LowPriorityQueue> watched_queue;
  {
    asio::io_context io(1);
    auto queue = LowPriorityQueue::create(io.get_executor(), 1);
    watched_queue = queue;
    // A coroutine suspended on the queue's executor holds the queue through its frame.
    asio::co_spawn(
        queue->executor(),
        [&io]() -> asio::awaitable<void> {
          asio::steady_timer timer(io, std::chrono::hours(1));
          co_await timer.async_wait(asio::use_awaitable);
        },
        [](std::exception_ptr) {});
    io.poll();  // the coroutine starts and waits on its timer
    ASSERT_EQ(queue->queued(), 0u);
    // Work queued and never run: its pass is posted, and the loop goes before running it.
    asio::post(queue->executor(), [w = std::move(witness)] {});
    ASSERT_EQ(queue->queued(), 1u);
    queue.reset();
  }
  EXPECT_TRUE(watched.expired());
  EXPECT_TRUE(watched_queue.expired()) << "the queue and its coroutine kept each other alive";
}

}  // namespace
}  // namespace canbridge::backbone
