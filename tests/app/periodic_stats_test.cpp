#include "app/periodic_stats.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

// The interval is in whole seconds: a disabled timer that gets 1 s must produce its first line
// after about a second, and a stopped one never again.
TEST(PeriodicStats, ANewIntervalArmsADisabledTimer) {
  boost::asio::io_context io;
  int lines = 0;
  PeriodicStats stats(io.get_executor(), 0s, [&] {
    ++lines;
    return std::string("line");
  });
  io.run_for(1200ms);
  EXPECT_EQ(lines, 0);  // 0 disables
  stats.set_interval(1s);
  EXPECT_EQ(stats.interval(), 1s);
  io.restart();
  const auto start = std::chrono::steady_clock::now();
  while (lines == 0 && std::chrono::steady_clock::now() - start < 5s) io.run_one_for(5s);
  EXPECT_EQ(lines, 1);
  EXPECT_GE(std::chrono::steady_clock::now() - start, 900ms);
  stats.stop();
  stats.set_interval(1s);  // ignored once stopped: nothing is pending, run() returns at once
  io.restart();
  io.run();
  EXPECT_EQ(lines, 1);
}

TEST(PeriodicStats, ZeroDisablesARunningTimer) {
  boost::asio::io_context io;
  int lines = 0;
  PeriodicStats stats(io.get_executor(), 1s, [&] {
    ++lines;
    return std::string("line");
  });
  stats.set_interval(0s);
  io.run();  // nothing pending: returns without a line
  EXPECT_EQ(lines, 0);
}

}  // namespace
}  // namespace canbridge::bridge
