// TcpServer's admission control over loopback: pending connections are capped (the oldest goes),
// closed at the handshake deadline unless admitted, slow upgrades cancelled, admitted links capped.
#include <gtest/gtest.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <string>

#include "backbone/tcp_server.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;
using testing::run_until;
using Clock = std::chrono::steady_clock;

// A raw client that says nothing (or one byte) and notes when the server closes the connection.
class SilentClient {
 public:
  // `talk`: sends one byte after connecting (then nothing more), as a peer starting a handshake.
  // `from`: the local address to connect from (another host, as far as the server can tell).
  SilentClient(asio::io_context& io, std::uint16_t port, bool talk = false,
               const char* from = nullptr)
      : state_(std::make_shared<State>(io)) {
    if (from) {
      state_->socket.open(tcp::v4());
      state_->socket.bind(tcp::endpoint(asio::ip::make_address(from), 0));
    }
    state_->socket.connect(tcp::endpoint(asio::ip::address_v4::loopback(), port));
    if (talk) asio::write(state_->socket, asio::buffer("\x00", 1));
    local_port = state_->socket.local_endpoint().port();
    // The state outlives this client until the read's handler ran.
    state_->socket.async_read_some(asio::buffer(&state_->byte, 1),
                                   [state = state_](boost::system::error_code ec, std::size_t) {
                                     state->closed_by_server = ec == asio::error::eof ||
                                                               ec == asio::error::connection_reset;
                                     state->closed_at = Clock::now();
                                   });
  }
  ~SilentClient() {
    boost::system::error_code ignored;
    state_->socket.close(ignored);
  }
  bool closed_by_server() const { return state_->closed_by_server; }
  Clock::time_point closed_at() const { return state_->closed_at; }
  std::uint16_t local_port = 0;

 private:
  struct State {
    explicit State(asio::io_context& io) : socket(io) {}
    tcp::socket socket;
    char byte = 0;
    bool closed_by_server = false;
    Clock::time_point closed_at;
  };
  std::shared_ptr<State> state_;
};

// An upgrade that waits forever (a TLS peer that stops mid-handshake) unless cancelled.
struct StuckUpgrade {
  int started = 0;
  int ended = 0;
  std::error_code last_error;
  LinkUpgrade upgrade() {
    return [this](tcp::socket socket, StreamLinkOptions) -> asio::awaitable<UpgradeResult> {
      ++started;
      asio::steady_timer never(socket.get_executor(), asio::steady_timer::time_point::max());
      auto [ec] = co_await never.async_wait(asio::as_tuple(asio::use_awaitable));
      ++ended;
      last_error = ec;
      co_return UpgradeResult{nullptr, ec};
    };
  }
};

// An upgrade of `steps` steps, each a turn of the loop (TLS work on each flight of the peer),
// noting 'L' in a trace the test shares with an established link's work.
struct SteppedUpgrade {
  std::string* trace = nullptr;
  int steps = 0;
  LinkUpgrade upgrade() {
    return [this](tcp::socket socket, StreamLinkOptions) -> asio::awaitable<UpgradeResult> {
      for (int i = 0; i < steps; ++i) {
        co_await asio::post(asio::use_awaitable);  // the coroutine's own executor
        *trace += 'L';
      }
      boost::system::error_code ignored;
      socket.close(ignored);
      co_return UpgradeResult{nullptr, std::make_error_code(std::errc::permission_denied)};
    };
  }
};

class TcpAdmission : public ::testing::Test {
 protected:
  void start(AdmissionLimits limits, LinkUpgrade upgrade = {},
             std::size_t handshake_steps_per_pass = ServerOptions{}.handshake_steps_per_pass) {
    ServerOptions options;
    options.admission = limits;
    options.upgrade = std::move(upgrade);
    options.handshake_steps_per_pass = handshake_steps_per_pass;
    server = TcpServer::create(io.get_executor(), options);
    const auto ec = server->start("127.0.0.1", 0, [this](std::shared_ptr<StreamLink> link) {
      accepted.push_back(link);
      link->start([](std::span<const std::uint8_t>) {}, [](std::string&) {}, nullptr);
      if (admit_every_link) server->admitted(*link);
    });
    ASSERT_FALSE(ec) << ec.message();
  }
  void TearDown() override {
    if (server) server->stop();
    clients.clear();
    accepted.clear();
    EXPECT_TRUE(testing::drains_within(io, 2s)) << "a connection's coroutine did not end";
  }
  SilentClient& connect(bool talk = false, const char* from = nullptr) {
    clients.push_back(std::make_unique<SilentClient>(io, server->port(), talk, from));
    return *clients.back();
  }
  // Waits until the server has handed `n` links over.
  bool accepted_count(std::size_t n) {
    return run_until(
        io, [&] { return accepted.size() >= n; }, 5s);
  }
  std::vector<std::uint16_t> open_link_ports() {
    std::vector<std::uint16_t> ports;
    for (const auto& link : server->links()) ports.push_back(link->remote_endpoint().port());
    std::sort(ports.begin(), ports.end());
    return ports;
  }

  StuckUpgrade stuck;  // outlives the server's coroutines
  asio::io_context io;
  std::shared_ptr<TcpServer> server;
  std::vector<std::shared_ptr<StreamLink>> accepted;
  std::vector<std::unique_ptr<SilentClient>> clients;
  bool admit_every_link = false;
};

TEST_F(TcpAdmission, IdleConnectionsBeyondThePendingCapEvictTheOldest) {
  start({3, 10s, 10});
  SilentClient& oldest = connect();
  for (int i = 0; i < 3; ++i) connect();
  ASSERT_TRUE(run_until(
      io, [&] { return oldest.closed_by_server(); }, 5s));
  ASSERT_TRUE(run_until(
      io, [&] { return server->connections() == 3; }, 5s));
  EXPECT_EQ(server->counters().admission.evicted_pending, 1u);
  EXPECT_EQ(server->counters().admission.pending_peak, 3u);
  for (std::size_t i = 1; i < clients.size(); ++i) EXPECT_FALSE(clients[i]->closed_by_server());
  EXPECT_TRUE(accepted.empty()) << "a silent connection got a link";
}

TEST_F(TcpAdmission, AConnectionWhosePeerSpokeOutlivesSilentOnesBeyondTheCap) {
  start({3, 10s, 10});
  SilentClient& speaking = connect(true);
  ASSERT_TRUE(accepted_count(1));
  SilentClient& silent = connect();
  for (int i = 0; i < 3; ++i) connect();
  ASSERT_TRUE(run_until(
      io, [&] { return silent.closed_by_server(); }, 5s));
  ASSERT_TRUE(run_until(
      io, [&] { return server->counters().admission.evicted_pending == 2; }, 5s));
  EXPECT_FALSE(speaking.closed_by_server());
  EXPECT_TRUE(accepted[0]->is_open());
  EXPECT_EQ(server->counters().admission.evicted_talking, 0u);
}

TEST_F(TcpAdmission, ASourceBeyondItsBudgetIsClosedAtAcceptWhileAnotherSourceIsServed) {
  start({32, 10s, 10, {2, 10s, 1024}}, stuck.upgrade());
  SilentClient& first = connect(true, "127.0.0.2");
  SilentClient& second = connect(true, "127.0.0.2");
  SilentClient& third = connect(true, "127.0.0.2");
  ASSERT_TRUE(run_until(
      io, [&] { return third.closed_by_server(); }, 5s));
  SilentClient& other_host = connect(true, "127.0.0.1");
  ASSERT_TRUE(run_until(
      io, [&] { return stuck.started == 3; }, 5s));
  EXPECT_FALSE(first.closed_by_server());
  EXPECT_FALSE(second.closed_by_server());
  EXPECT_FALSE(other_host.closed_by_server());
  EXPECT_EQ(server->counters().admission.per_source.refused, 1u);
  EXPECT_EQ(server->connections(), 3u);  // nothing was kept of the refused one
}

TEST_F(TcpAdmission, AConnectionPastItsHandshakeNoLongerHoldsItsSourcesBudget) {
  // Plain: the upgrade completes at once; the links stay pending (never admitted).
  start({32, 10s, 10, {1, 10s, 1024}});
  SilentClient& first = connect(true, "127.0.0.2");
  ASSERT_TRUE(accepted_count(1));
  SilentClient& second = connect(true, "127.0.0.2");
  ASSERT_TRUE(accepted_count(2));
  EXPECT_FALSE(first.closed_by_server());
  EXPECT_FALSE(second.closed_by_server());
  EXPECT_EQ(server->counters().admission.per_source.refused, 0u);
}

TEST_F(TcpAdmission, AConnectionThatSaysNothingIsClosedAtTheDeadlineAndNothingIsKept) {
  start({32, 300ms, 10});
  const auto connected_at = Clock::now();
  SilentClient& silent = connect();
  ASSERT_TRUE(run_until(
      io, [&] { return silent.closed_by_server(); }, 5s));
  EXPECT_GE(silent.closed_at() - connected_at, 300ms);
  EXPECT_LT(silent.closed_at() - connected_at, 2s);
  EXPECT_EQ(server->counters().admission.handshake_timeouts, 1u);
  accepted.clear();
  ASSERT_TRUE(run_until(
      io, [&] { return server->connections() == 0; }, 5s));
  EXPECT_TRUE(server->links().empty());
}

TEST_F(TcpAdmission, AnAdmittedLinkIsNotClosedAtTheDeadline) {
  start({32, 200ms, 10});
  SilentClient& admitted = connect(true);
  ASSERT_TRUE(accepted_count(1));
  server->admitted(*accepted[0]);
  SilentClient& pending = connect();  // its deadline is later than the admitted one's was
  ASSERT_TRUE(run_until(
      io, [&] { return pending.closed_by_server(); }, 5s));
  EXPECT_FALSE(admitted.closed_by_server());
  EXPECT_TRUE(accepted[0]->is_open());
  EXPECT_EQ(server->counters().admission.handshake_timeouts, 1u);
  EXPECT_EQ(server->counters().admission.admitted, 1u);
}

TEST_F(TcpAdmission, AStuckUpgradeIsCancelledAtTheDeadlineAndItsCoroutineEnds) {
  start({32, 300ms, 10}, stuck.upgrade());
  const auto connected_at = Clock::now();
  SilentClient& client = connect(true);
  ASSERT_TRUE(run_until(
      io, [&] { return stuck.ended == 1; }, 5s));
  EXPECT_GE(Clock::now() - connected_at, 300ms);
  EXPECT_TRUE(stuck.last_error == std::errc::operation_canceled) << stuck.last_error.message();
  ASSERT_TRUE(run_until(
      io, [&] { return client.closed_by_server(); }, 5s));
  ASSERT_TRUE(run_until(
      io, [&] { return server->connections() == 0; }, 5s));
  EXPECT_EQ(server->counters().upgrade_failures, 1u);
  EXPECT_EQ(server->counters().admission.handshake_timeouts, 1u);
  EXPECT_TRUE(accepted.empty());
}

TEST_F(TcpAdmission, AStuckUpgradeIsCancelledWhenANewerConnectionEvictsIt) {
  start({1, 60s, 10}, stuck.upgrade());
  SilentClient& first = connect(true);
  ASSERT_TRUE(run_until(
      io, [&] { return stuck.started == 1; }, 5s));
  connect(true);
  ASSERT_TRUE(run_until(
      io, [&] { return stuck.ended == 1 && first.closed_by_server(); }, 5s));
  EXPECT_EQ(server->counters().admission.evicted_pending, 1u);
  EXPECT_EQ(server->connections(), 1u);  // the newer one, still upgrading
}

TEST_F(TcpAdmission, LinksBeyondMaxLinksAreClosedWhenAdmitted) {
  admit_every_link = true;
  start({32, 60s, 2});
  connect(true);
  connect(true);
  SilentClient& third = connect(true);
  ASSERT_TRUE(run_until(
      io, [&] { return third.closed_by_server(); }, 5s));
  EXPECT_EQ(server->counters().admission.refused_link_cap, 1u);
  EXPECT_EQ(server->counters().admission.admitted, 2u);
  std::vector<std::uint16_t> first_two{clients[0]->local_port, clients[1]->local_port};
  std::sort(first_two.begin(), first_two.end());
  EXPECT_EQ(open_link_ports(), first_two);
}

TEST_F(TcpAdmission, ManyShortConnectionsLeaveNothingBehind) {
  start({4, 60s, 10});
  for (int i = 0; i < 50; ++i) connect(i % 2 == 0);
  ASSERT_TRUE(run_until(
      io, [&] { return server->counters().accepted == 50; }, 5s));
  clients.clear();  // the peers leave: each link reads EOF and closes
  accepted.clear();
  ASSERT_TRUE(run_until(
      io, [&] { return server->connections() == 0; }, 5s));
  EXPECT_EQ(server->counters().admission.evicted_pending, 46u);
}

TEST_F(TcpAdmission, AfterManyConnectionsTheFreedHeapIsGivenBackOnceNothingIsPending) {
  start({4, 60s, 10});
  for (int i = 0; i < 300; ++i) connect(i % 2 == 0);
  ASSERT_TRUE(run_until(
      io, [&] { return server->counters().accepted == 300; }, 5s));
  // Evictions kept 4 pending all along: no trim while a flood still runs.
  EXPECT_EQ(server->counters().heap_trims, 0u);
  clients.clear();
  accepted.clear();
  ASSERT_TRUE(run_until(
      io, [&] { return server->connections() == 0; }, 5s));
  EXPECT_EQ(server->counters().heap_trims, 1u);  // once, not once per connection
}

}  // namespace
}  // namespace canbridge::backbone

namespace canbridge::backbone {
namespace {

// An established link's work, ready again on every pass of the loop until `steps` handshake
// steps ran.
void keep_link_busy(asio::io_context& io, std::string& trace, std::size_t steps) {
  asio::post(io, [&io, &trace, steps] {
    if (static_cast<std::size_t>(std::count(trace.begin(), trace.end(), 'L')) >= steps) return;
    trace += 'E';
    keep_link_busy(io, trace, steps);
  });
}

TEST_F(TcpAdmission, HandshakeStepsRunInPassesBehindTheEstablishedLinks) {
  std::string trace;
  SteppedUpgrade stepped{&trace, 10};
  // A bound below the 8 handshakes, so that it shows; the default is one pass of every step.
  start({32, 60s, 10}, stepped.upgrade(), 3);
  keep_link_busy(io, trace, 80);
  for (int i = 0; i < 8; ++i) connect(true);  // a flood of handshakes, all ready at once
  ASSERT_TRUE(run_until(
      io, [&] { return std::count(trace.begin(), trace.end(), 'L') == 80; }, 5s))
      << trace;
  // Between two turns of the link's work, at most 3 steps ran: with the handshakes on the loop's
  // own executor, all eight ready steps ran in a row.
  std::size_t longest = 0;
  std::size_t run = 0;
  for (char c : trace) {
    run = c == 'L' ? run + 1 : 0;
    longest = std::max(longest, run);
  }
  EXPECT_LE(longest, 3u) << trace;
  EXPECT_GE(server->counters().handshake_steps.run, 80u);
  EXPECT_GT(server->counters().handshake_steps.deferred, 0u);
}

}  // namespace
}  // namespace canbridge::backbone
