#include <gtest/gtest.h>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::bytes;
using testing::run_until;
using testing::tcp_nodelay;
using testing::to_string;

ClientOptions fast_client() {
  ClientOptions options;
  options.backoff_min = 10ms;
  options.backoff_max = 40ms;
  options.connect_timeout = 2s;
  return options;
}

// Starts a link that only records what it receives; `sent` is sent once at start.
void start_recording(const std::shared_ptr<StreamLink>& link, std::vector<std::string>& received,
                     std::string sent = {}) {
  link->start([&received](std::span<const std::uint8_t> m) { received.push_back(to_string(m)); },
              [sent = std::move(sent), once = true](std::string& out) mutable {
                if (once && !sent.empty()) append_delimited(out, bytes(sent));
                once = false;
              },
              nullptr);
}

class ClientServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server = TcpServer::create(io.get_executor());
    const auto ec = server->start("127.0.0.1", 0, [this](std::shared_ptr<StreamLink> link) {
      accepted.push_back(link);
      start_recording(link, server_received, "welcome");
      if (drop_next_accept) {
        drop_next_accept = false;
        link->close();
      }
    });
    ASSERT_FALSE(ec) << ec.message();
    ASSERT_NE(server->port(), 0);
  }
  void TearDown() override {
    if (client) client->stop();
    server->stop();
    EXPECT_TRUE(testing::drains_within(io, 2s));
  }

  std::shared_ptr<TcpClient> make_client(std::uint16_t port,
                                         ClientOptions options = fast_client()) {
    client = TcpClient::create(io.get_executor(), "127.0.0.1", port, options);
    client->start([this](std::shared_ptr<StreamLink> link) {
      connected.push_back(link);
      start_recording(link, client_received, "hello " + std::to_string(connected.size()));
    });
    return client;
  }

  asio::io_context io;
  std::shared_ptr<TcpServer> server;
  std::shared_ptr<TcpClient> client;
  std::vector<std::shared_ptr<StreamLink>> accepted, connected;
  std::vector<std::string> server_received, client_received;
  bool drop_next_accept = false;
};

TEST_F(ClientServerTest, ClientConnectsAndBothSidesExchangeMessages) {
  make_client(server->port());
  ASSERT_TRUE(
      run_until(io, [&] { return server_received.size() == 1 && client_received.size() == 1; }));
  EXPECT_EQ(server_received[0], "hello 1");
  EXPECT_EQ(client_received[0], "welcome");
  EXPECT_EQ(client->counters().connects, 1u);
  EXPECT_EQ(client->counters().connect_failures, 0u);
  EXPECT_EQ(server->counters().accepted, 1u);
  EXPECT_EQ(client->link(), connected.at(0));
  EXPECT_EQ(server->links().size(), 1u);
}

TEST_F(ClientServerTest, TcpNoDelayIsOnForAcceptedAndConnectedSockets) {
  make_client(server->port());
  ASSERT_TRUE(run_until(io, [&] { return accepted.size() == 1 && connected.size() == 1; }));
  EXPECT_NE(tcp_nodelay(accepted[0]->native_handle()), 0);
  EXPECT_NE(tcp_nodelay(connected[0]->native_handle()), 0);
}

TEST_F(ClientServerTest, ServerAcceptsManyClients) {
  std::vector<std::shared_ptr<TcpClient>> clients;
  for (int i = 0; i < 5; ++i) {
    clients.push_back(TcpClient::create(io.get_executor(), "127.0.0.1", server->port()));
    clients.back()->start(
        [this](std::shared_ptr<StreamLink> link) { start_recording(link, client_received); });
  }
  ASSERT_TRUE(run_until(io, [&] { return client_received.size() == 5; }));
  EXPECT_EQ(server->links().size(), 5u);
  for (auto& c : clients) c->stop();
}

TEST_F(ClientServerTest, ClientReconnectsAfterTheServerDropsTheLink) {
  drop_next_accept = true;
  make_client(server->port());
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connects == 2; }));
  ASSERT_TRUE(run_until(io, [&] { return server_received.size() == 1; }));
  EXPECT_EQ(server_received[0], "hello 2");  // the first link was dropped before it was read
  EXPECT_EQ(connected.size(), 2u);
  EXPECT_FALSE(connected[0]->is_open());
  EXPECT_EQ(connected[0]->counters().close_reason, errc::peer_closed);
  EXPECT_EQ(client->counters().connect_failures, 0u);
}

TEST_F(ClientServerTest, ClientBacksOffWhileNothingListens) {
  ClientOptions options;
  options.backoff_min = 20ms;
  options.backoff_max = 80ms;
  const auto start = std::chrono::steady_clock::now();
  make_client(testing::unused_port(io), options);
  // Attempts at 0, 20, 60, 140, 220 ms: the waits double up to the maximum.
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connect_failures == 5; }));
  const auto elapsed = std::chrono::steady_clock::now() - start;
  EXPECT_GE(elapsed, 20ms + 40ms + 80ms + 80ms);
  EXPECT_EQ(client->counters().connects, 0u);
  EXPECT_EQ(client->link(), nullptr);
}

TEST_F(ClientServerTest, AClientThePeerRefusesWaitsTwiceAsLongEachTimeUpToTheMaximum) {
  // What a session does when the peer's Refusal arrives: close with errc::refused_by_peer. Each
  // new connection must not count as a success: the same hello is refused again.
  std::vector<std::chrono::steady_clock::time_point> at;
  client = TcpClient::create(io.get_executor(), "127.0.0.1", server->port(), fast_client());
  client->start([&](std::shared_ptr<StreamLink> link) {
    at.push_back(std::chrono::steady_clock::now());
    start_recording(link, client_received);
    link->close(make_error_code(errc::refused_by_peer));
  });
  ASSERT_TRUE(run_until(io, [&] { return at.size() >= 6; }));
  const std::vector<std::chrono::milliseconds> schedule{10ms, 20ms, 40ms, 40ms, 40ms};
  for (std::size_t i = 0; i < schedule.size(); ++i) {
    EXPECT_GE(at[i + 1] - at[i], schedule[i]) << "attempt " << i + 2;
  }
  EXPECT_EQ(client->counters().connect_failures, 0u);
}

TEST_F(ClientServerTest, ClientConnectsOnceTheServerAppears) {
  // Starts against a dead port, then a server comes up there: backoff must not give up.
  const std::uint16_t port = testing::unused_port(io);
  make_client(port);
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connect_failures >= 2; }));
  auto late = TcpServer::create(io.get_executor());
  std::vector<std::string> late_received;
  ASSERT_FALSE(late->start("127.0.0.1", port, [&](std::shared_ptr<StreamLink> link) {
    start_recording(link, late_received);
  }));
  ASSERT_TRUE(run_until(io, [&] { return late_received.size() == 1; }));
  EXPECT_EQ(client->counters().connects, 1u);
  late->stop();
}

TEST_F(ClientServerTest, StopOfClientAndServerLeavesNothingPending) {
  make_client(server->port());
  ASSERT_TRUE(run_until(io, [&] { return server_received.size() == 1; }));
  std::weak_ptr<TcpClient> weak_client = client;
  std::weak_ptr<TcpServer> weak_server = server;
  std::weak_ptr<StreamLink> weak_link = connected.at(0);
  connected.clear();
  accepted.clear();

  const auto start = std::chrono::steady_clock::now();
  client->stop();
  server->stop();
  client.reset();
  server->stop();  // idempotent
  EXPECT_TRUE(testing::drains_within(io, 2s));
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
  EXPECT_TRUE(weak_client.expired());
  EXPECT_TRUE(weak_link.expired());
  server.reset();
  EXPECT_TRUE(weak_server.expired());
  server = TcpServer::create(io.get_executor());  // for TearDown
}

TEST_F(ClientServerTest, StopDuringBackoffIsPrompt) {
  ClientOptions options;
  options.backoff_min = 10s;  // a stop must not wait for this
  make_client(testing::unused_port(io), options);
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connect_failures == 1; }));
  const auto start = std::chrono::steady_clock::now();
  client->stop();
  server->stop();
  EXPECT_TRUE(testing::drains_within(io, 2s));
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
}

// A listener whose accept queue is full silently drops further SYNs (Linux): a connect to it
// hangs like one to a vanished host.
struct FullListener {
  explicit FullListener(asio::io_context& io)
      : acceptor(io, asio::ip::tcp::endpoint(asio::ip::address_v4::loopback(), 0), false),
        filler(io) {
    acceptor.listen(0);
    filler.connect(acceptor.local_endpoint());
  }
  std::uint16_t port() const { return acceptor.local_endpoint().port(); }
  asio::ip::tcp::acceptor acceptor;
  asio::ip::tcp::socket filler;
};

TEST_F(ClientServerTest, StopDuringConnectIsPrompt) {
  FullListener full(io);
  ClientOptions options;
  options.connect_timeout = 30s;
  make_client(full.port(), options);
  ASSERT_TRUE(run_until(io, [&] { return client->counters().attempts == 1; }));
  io.poll();
  EXPECT_EQ(client->counters().connect_failures, 0u);  // still connecting
  const auto start = std::chrono::steady_clock::now();
  client->stop();
  server->stop();
  EXPECT_TRUE(testing::drains_within(io, 2s));
  EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
  EXPECT_EQ(client->counters().connects, 0u);
}

TEST_F(ClientServerTest, ConnectTimeoutCountsAsFailure) {
  FullListener full(io);
  ClientOptions options;
  options.connect_timeout = 50ms;
  options.backoff_min = 10ms;
  options.backoff_max = 10ms;
  const auto start = std::chrono::steady_clock::now();
  make_client(full.port(), options);
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connect_failures >= 2; }));
  EXPECT_GE(std::chrono::steady_clock::now() - start, 50ms + 10ms + 50ms);
  EXPECT_EQ(client->counters().connects, 0u);
  // The deadline covers resolving too, so on a loaded machine a failure may precede the connect.
  EXPECT_GE(client->counters().attempts, 1u);
}

TEST_F(ClientServerTest, ServerStopClosesLiveLinks) {
  make_client(server->port());
  ASSERT_TRUE(run_until(io, [&] { return accepted.size() == 1 && connected.size() == 1; }));
  server->stop();
  EXPECT_FALSE(accepted[0]->is_open());
  EXPECT_EQ(accepted[0]->counters().close_reason, errc::closed);
  // The client notices and starts reconnecting (to nothing).
  ASSERT_TRUE(run_until(io, [&] { return client->counters().connect_failures >= 1; }));
  EXPECT_EQ(connected[0]->counters().close_reason, errc::peer_closed);
}

TEST_F(ClientServerTest, StartFailsOnBadAddressOrBusyPort) {
  auto other = TcpServer::create(io.get_executor());
  EXPECT_TRUE(other->start("not-an-address", 0, nullptr));
  auto busy = TcpServer::create(io.get_executor());
  EXPECT_TRUE(busy->start("127.0.0.1", server->port(), nullptr));
  EXPECT_EQ(busy->port(), 0);
}

}  // namespace
}  // namespace canbridge::backbone
