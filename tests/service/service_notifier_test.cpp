// ServiceNotifier speaks sd_notify(3)'s protocol to a real AF_UNIX datagram socket: READY with
// STATUS, STATUS, STOPPING, watchdog keep-alives at half the timeout from the loop's own timer
// (none while the loop stalls, none for another process's watchdog), abstract socket names, and
// nothing at all outside systemd.
#include "app/service_notifier.hpp"

#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <cstdlib>
#include <random>
#include <thread>

#include "tests/support/notify_listener.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using test::NotifyListener;

std::string unique_name() {
  return "canbridge-notify-" + std::to_string(::getpid()) + "-" +
         std::to_string(std::random_device{}());
}

NotifyEnvironment environment(const std::string& socket, std::chrono::microseconds watchdog = 0us) {
  NotifyEnvironment env;
  env.socket = socket;
  env.watchdog_timeout = watchdog;
  return env;
}

TEST(ServiceNotifier, ReadyCarriesTheStatusThenStatusAndStoppingFollow) {
  NotifyListener listener(::testing::TempDir() + unique_name());
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor(), environment(listener.address()));
  ASSERT_TRUE(notifier.enabled());
  notifier.ready("gateway g: 2 module(s) open");
  EXPECT_EQ(listener.receive(2s), "READY=1\nSTATUS=gateway g: 2 module(s) open");
  notifier.status("link up");
  EXPECT_EQ(listener.receive(2s), "STATUS=link up");
  notifier.stopping();
  EXPECT_EQ(listener.receive(2s), "STOPPING=1\nSTATUS=stopping");
}

TEST(ServiceNotifier, ReachesAnAbstractSocket) {
  NotifyListener listener("@" + unique_name());
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor(), environment(listener.address()));
  notifier.ready("up");
  EXPECT_EQ(listener.receive(2s), "READY=1\nSTATUS=up");
}

TEST(ServiceNotifier, PetsTheWatchdogAtHalfItsTimeoutFromTheLoop) {
  NotifyListener listener("@" + unique_name());
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor(), environment(listener.address(), 20ms));
  EXPECT_EQ(notifier.watchdog_period(), 10ms);
  notifier.ready("up");
  ASSERT_EQ(listener.receive(2s), "READY=1\nSTATUS=up");
  // A loop that does not run does not pet: a stalled role gets restarted.
  EXPECT_EQ(listener.receive(50ms), std::nullopt);
  const auto start = std::chrono::steady_clock::now();
  io.run_for(200ms);
  const auto ran = std::chrono::steady_clock::now() - start;
  const int pets = listener.drain();
  // Never faster than every 10 ms; at least a few even on a loaded machine.
  EXPECT_LE(pets, 1 + ran / 10ms);  // the first one fell due while the loop stalled
  EXPECT_GE(pets, 5);
  // Stopping ends the keep-alives: nothing is left for the loop to do.
  notifier.stopping();
  EXPECT_EQ(listener.receive(2s), "STOPPING=1\nSTATUS=stopping");
  io.restart();
  io.run_for(100ms);
  EXPECT_TRUE(io.stopped());  // ran out of work: the timer was not armed again
  EXPECT_EQ(listener.drain(), 0);
}

TEST(ServiceNotifier, AKeepAliveAlreadyDueIsNotSentAfterStopping) {
  NotifyListener listener("@" + unique_name());
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor(), environment(listener.address(), 20ms));
  notifier.ready("up");
  ASSERT_EQ(listener.receive(2s), "READY=1\nSTATUS=up");
  // Shutdown begins from a handler that runs in the same turn of the loop as the keep-alive
  // falling due: both timers expired during the stall, the earlier one's handler runs first.
  boost::asio::steady_timer shutdown(io, std::chrono::steady_clock::now() + 5ms);
  shutdown.async_wait([&](boost::system::error_code) { notifier.stopping(); });
  boost::asio::post(io, [] { std::this_thread::sleep_for(30ms); });
  io.run_for(200ms);
  EXPECT_TRUE(io.stopped());  // nothing re-armed
  EXPECT_EQ(listener.receive(2s), "STOPPING=1\nSTATUS=stopping");
  EXPECT_EQ(listener.drain(), 0);
}

TEST(ServiceNotifier, AnotherProcesssWatchdogIsNotPetted) {
  NotifyListener listener("@" + unique_name());
  boost::asio::io_context io;
  NotifyEnvironment env = environment(listener.address(), 20ms);
  env.watchdog_pid = ::getpid() + 1;
  ServiceNotifier notifier(io.get_executor(), env);
  EXPECT_EQ(notifier.watchdog_period(), 0us);
  notifier.ready("up");
  EXPECT_EQ(listener.receive(2s), "READY=1\nSTATUS=up");  // readiness is still ours to tell
  EXPECT_EQ(io.run_for(100ms), 0u);
  EXPECT_EQ(listener.drain(), 0);
}

TEST(ServiceNotifier, OurOwnWatchdogPidIsPetted) {
  NotifyListener listener("@" + unique_name());
  boost::asio::io_context io;
  NotifyEnvironment env = environment(listener.address(), 20ms);
  env.watchdog_pid = ::getpid();
  ServiceNotifier notifier(io.get_executor(), env);
  notifier.ready("up");
  io.run_for(100ms);
  EXPECT_GE(listener.drain(), 1);
}

TEST(ServiceNotifier, ReadsTheEnvironmentSystemdSets) {
  ::setenv("NOTIFY_SOCKET", "@some-name", 1);
  ::setenv("WATCHDOG_USEC", "3000000", 1);
  ::setenv("WATCHDOG_PID", std::to_string(::getpid()).c_str(), 1);
  NotifyEnvironment env = NotifyEnvironment::from_process();
  EXPECT_EQ(env.socket, "@some-name");
  EXPECT_EQ(env.watchdog_timeout, 3s);
  EXPECT_EQ(env.watchdog_pid, ::getpid());
  ::setenv("WATCHDOG_USEC", "3s", 1);  // malformed: no watchdog rather than a wrong one
  ::unsetenv("WATCHDOG_PID");
  env = NotifyEnvironment::from_process();
  EXPECT_EQ(env.watchdog_timeout, 0us);
  EXPECT_EQ(env.watchdog_pid, std::nullopt);
  ::unsetenv("NOTIFY_SOCKET");
  ::unsetenv("WATCHDOG_USEC");
}

TEST(ServiceNotifier, WithoutNotifySocketDoesNothing) {
  ::unsetenv("NOTIFY_SOCKET");
  ::setenv("WATCHDOG_USEC", "20000", 1);
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor());
  ::unsetenv("WATCHDOG_USEC");
  EXPECT_FALSE(notifier.enabled());
  notifier.ready("up");
  notifier.status("x");
  // No timer was armed: the loop has nothing to run.
  EXPECT_EQ(io.run_for(50ms), 0u);
  notifier.stopping();
}

TEST(ServiceNotifier, AnUnreachableManagerIsLoggedOnceAndNeverFatal) {
  auto sink = std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(16);
  auto previous = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>("notify-test", sink));
  {
    boost::asio::io_context io;
    ServiceNotifier notifier(io.get_executor(),
                             environment(::testing::TempDir() + unique_name(), 20ms));
    notifier.ready("up");  // nobody bound that path
    io.run_for(60ms);      // a few failed keep-alives
    notifier.stopping();
  }
  spdlog::set_default_logger(previous);
  const auto lines = sink->last_formatted();
  int failures = 0;
  for (const std::string& line : lines) {
    if (line.find("cannot notify systemd") != std::string::npos) ++failures;
  }
  EXPECT_EQ(failures, 1) << ::testing::PrintToString(lines);
}

TEST(ServiceNotifier, ARelativePathIsRefused) {
  boost::asio::io_context io;
  ServiceNotifier notifier(io.get_executor(), environment("relative/socket", 20ms));
  EXPECT_FALSE(notifier.enabled());
  notifier.ready("up");
  EXPECT_EQ(io.run_for(50ms), 0u);
}

}  // namespace
}  // namespace canbridge::bridge
