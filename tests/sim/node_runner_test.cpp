// End to end on one io_context: simulated nodes (NodeRunner) and an SDO client (SdoClientChannel)
// on a can::VirtualBus. Every wait is on an event; io_context::run_for only bounds a broken test.
#include "sim/node_runner.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/experimental/awaitable_operators.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <functional>

#include "can/virtual_bus.hpp"
#include "canopen/sdo_client.hpp"
#include "tests/support/spawn_checked.hpp"

namespace canbridge::sim {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using can::Frame;
using canopen::SdoAbort;
using canopen::SdoResult;
using Bytes = std::vector<std::uint8_t>;

constexpr auto kTestLimit = 10s;

NodeSpec spec_of(canopen::NodeId id) {
  NodeSpec c;
  c.kind = NodeKind::microcanopen;
  c.node_id = id;
  c.identity = {0x000001A2, 0x00000100u + id, 0x00010000, 0x1000u + id};
  return c;
}

struct Rig {
  Rig() {
    channel.set_observer([this](const Frame& f) {
      seen.push_back(f);
      seen_signal.cancel();
    });
  }

  // Runs `body` while the runner and the channel serve the bus, then stops both. True when
  // everything finished within kTestLimit.
  bool run(std::function<asio::awaitable<void>()> body) {
    bool done = false;
    test::spawn_checked(io, runner.run());
    test::spawn_checked(io, channel.run());
    test::spawn_checked(io, [&]() -> asio::awaitable<void> {
      co_await body();
      done = true;
      runner.stop();
      channel.stop();
    });
    io.run_for(kTestLimit);
    return done && io.stopped();
  }

  // Waits until a frame seen by the channel makes `condition` true.
  asio::awaitable<void> wait_until(std::function<bool()> condition) {
    while (!condition()) {
      seen_signal.expires_at(asio::steady_timer::time_point::max());
      co_await seen_signal.async_wait(asio::as_tuple(asio::use_awaitable));
    }
  }

  std::size_t count(const Frame& frame) const {
    return static_cast<std::size_t>(std::count(seen.begin(), seen.end(), frame));
  }

  asio::io_context io;
  can::VirtualBus medium{io.get_executor(), "vbus"};
  std::unique_ptr<can::Bus> sim_end = medium.connect("sim");
  std::unique_ptr<can::Bus> client_end = medium.connect("client");
  NodeRunner runner{io.get_executor(), *sim_end};
  canopen::SdoClientChannel channel{io.get_executor(), *client_end};
  asio::steady_timer seen_signal{io};
  std::vector<Frame> seen;
};

TEST(NodeRunnerEndToEnd, BootUpsThenSdoUploadOfIdentity) {
  Rig rig;
  rig.runner.add(spec_of(5));
  rig.runner.add(spec_of(6));
  SdoResult vendor, product;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    vendor = co_await rig.channel.upload(5, 0x1018, 1, 1s);
    product = co_await rig.channel.upload(6, 0x1018, 2, 1s);
  }));
  ASSERT_GE(rig.seen.size(), 2u);
  EXPECT_EQ(rig.seen[0], Frame::standard(0x705, {0x00}));
  EXPECT_EQ(rig.seen[1], Frame::standard(0x706, {0x00}));
  ASSERT_TRUE(vendor.ok()) << vendor.error.message();
  EXPECT_EQ(vendor.data, (Bytes{0xA2, 0x01, 0x00, 0x00}));
  ASSERT_TRUE(product.ok()) << product.error.message();
  EXPECT_EQ(product.data, (Bytes{0x06, 0x01, 0x00, 0x00}));
  EXPECT_EQ(rig.runner.dropped_frames(), 0u);
}

TEST(NodeRunnerEndToEnd, AbortFromTheNodeArrivesAsSdoAbort) {
  Rig rig;
  rig.runner.add(spec_of(5));
  SdoResult missing, read_only;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    missing = co_await rig.channel.upload(5, 0x2000, 0, 1s);
    const std::uint8_t value[] = {1, 2, 3, 4};
    read_only = co_await rig.channel.download(5, 0x1018, 1, value, 1s);
  }));
  EXPECT_EQ(missing.error, SdoAbort::no_object);
  EXPECT_EQ(read_only.error, SdoAbort::write_read_only);
}

TEST(NodeRunnerEndToEnd, HeartbeatFollowsAPeriodDownloadedOverSdo) {
  Rig rig;
  rig.runner.add(spec_of(5));
  SdoResult write;
  const Frame heartbeat = Frame::standard(0x705, {0x7F});
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    const std::uint8_t period_10ms[] = {10, 0};
    write = co_await rig.channel.download(5, 0x1017, 0, period_10ms, 1s);
    // With the default 1000 ms these would take seconds; kTestLimit would catch a missed change.
    co_await rig.wait_until([&] { return rig.count(heartbeat) >= 3; });
  }));
  EXPECT_TRUE(write.ok()) << write.error.message();
  EXPECT_GE(rig.count(heartbeat), 3u);
}

TEST(NodeRunnerEndToEnd, NmtStartShowsInTheHeartbeat) {
  Rig rig;
  rig.runner.add(spec_of(5));
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    const std::uint8_t period_10ms[] = {10, 0};
    co_await rig.channel.download(5, 0x1017, 0, period_10ms, 1s);
    rig.client_end->send(Frame::standard(0x000, {0x01, 0x00}));
    co_await rig.wait_until([&] { return rig.count(Frame::standard(0x705, {0x05})) >= 1; });
  }));
  EXPECT_EQ(rig.runner.nodes().front()->state(), canopen::NmtState::operational);
}

TEST(NodeRunnerEndToEnd, RequestsToOneNodeQueueAndOthersRunAlongside) {
  Rig rig;
  rig.runner.add(spec_of(5));
  rig.runner.add(spec_of(6));
  std::tuple<SdoResult, SdoResult, SdoResult> results;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    using namespace asio::experimental::awaitable_operators;
    results =
        co_await (rig.channel.upload(5, 0x1018, 2, 1s) && rig.channel.upload(5, 0x1018, 4, 1s) &&
                  rig.channel.upload(6, 0x1018, 4, 1s));
  }));
  const auto& [a, b, c] = results;
  EXPECT_EQ(a.data, (Bytes{0x05, 0x01, 0x00, 0x00}));
  EXPECT_EQ(b.data, (Bytes{0x05, 0x10, 0x00, 0x00}));
  EXPECT_EQ(c.data, (Bytes{0x06, 0x10, 0x00, 0x00}));
}

TEST(NodeRunnerEndToEnd, AbsentNodeTimesOutWith05040000) {
  Rig rig;
  rig.runner.add(spec_of(5));
  SdoResult result;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    result = co_await rig.channel.upload(42, 0x1000, 0, 20ms);
  }));
  EXPECT_EQ(result.error, SdoAbort::timeout);
  EXPECT_EQ(result.error.value(), 0x05040000);
}

TEST(NodeRunnerEndToEnd, StopFailsPendingAndLaterRequests) {
  Rig rig;
  SdoResult pending, later;
  bool pending_done = false;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    test::spawn_checked(rig.io, [&]() -> asio::awaitable<void> {
      pending = co_await rig.channel.upload(42, 0x1000, 0, 60s);
      pending_done = true;
      rig.seen_signal.cancel();  // wakes wait_until below
    });
    co_await asio::post(rig.io, asio::use_awaitable);  // let the request go out
    rig.channel.stop();
    co_await rig.wait_until([&] { return pending_done; });
    later = co_await rig.channel.upload(42, 0x1000, 0, 60s);
  }));
  EXPECT_EQ(pending.error, std::errc::operation_canceled);
  EXPECT_EQ(later.error, std::errc::operation_canceled);
}

TEST(NodeRunnerEndToEnd, NodeAddedWhileRunningBootsAtOnce) {
  Rig rig;
  rig.runner.add(spec_of(5));
  SdoResult result;
  ASSERT_TRUE(rig.run([&]() -> asio::awaitable<void> {
    co_await rig.wait_until([&] { return rig.count(Frame::standard(0x705, {0x00})) == 1; });
    rig.runner.add(spec_of(7));
    co_await rig.wait_until([&] { return rig.count(Frame::standard(0x707, {0x00})) == 1; });
    result = co_await rig.channel.upload(7, 0x1000, 0, 1s);
  }));
  EXPECT_EQ(result.data, (Bytes{0x91, 0x01, 0x00, 0x00}));
}

TEST(NodeRunner, ClosingTheBusEndsRun) {
  asio::io_context io;
  can::VirtualBus medium(io.get_executor(), "vbus");
  auto end = medium.connect("sim");
  NodeRunner runner(io.get_executor(), *end);
  runner.add(spec_of(1));
  bool finished = false;
  test::spawn_checked(io, [&]() -> asio::awaitable<void> {
    co_await runner.run();
    finished = true;
  });
  io.poll();
  EXPECT_FALSE(finished);
  end->close();
  io.run_for(kTestLimit);
  EXPECT_TRUE(finished);
  EXPECT_TRUE(io.stopped());
}

}  // namespace
}  // namespace canbridge::sim
