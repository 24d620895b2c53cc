// The roles' statistics endpoints on real sockets: the Prometheus endpoint over a loopback TCP
// connection (GET /metrics, 404 for anything else, keep-alive, the connection bound, loopback
// only) and the gateway's stats endpoint over a Unix socket.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/local/stream_protocol.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/read_until.hpp>
#include <boost/asio/streambuf.hpp>
#include <boost/asio/write.hpp>
#include <filesystem>
#include <thread>

#include "bridge/metrics_endpoint.hpp"
#include "bridge/stats_endpoint.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using namespace std::chrono_literals;

// The endpoint's loop on a thread of its own, so the test can be a plain blocking client.
class LoopThread {
 public:
  void run() {
    thread_ = std::thread([this] { io.run(); });
  }
  template <typename F>
  void stop(F&& last) {
    asio::post(io, [&] {
      last();
      work_.reset();
    });
    thread_.join();
  }
  ~LoopThread() {
    if (thread_.joinable()) {
      work_.reset();
      io.stop();
      thread_.join();
    }
  }
  asio::io_context io;

 private:
  std::optional<asio::executor_work_guard<asio::io_context::executor_type>> work_{
      asio::make_work_guard(io)};
  std::thread thread_;
};

// Sends `request` and reads one HTTP response (headers and a Content-Length body).
std::string exchange(tcp::socket& socket, const std::string& request) {
  asio::write(socket, asio::buffer(request));
  asio::streambuf buffer;
  const std::size_t header_end = asio::read_until(socket, buffer, "\r\n\r\n");
  std::string text(asio::buffers_begin(buffer.data()),
                   asio::buffers_begin(buffer.data()) + static_cast<std::ptrdiff_t>(header_end));
  buffer.consume(header_end);
  std::size_t length = 0;
  const auto at = text.find("Content-Length: ");
  if (at != std::string::npos) length = std::stoul(text.substr(at + 16));
  if (buffer.size() < length)
    asio::read(socket, buffer, asio::transfer_exactly(length - buffer.size()));
  text.append(asio::buffers_begin(buffer.data()),
              asio::buffers_begin(buffer.data()) + static_cast<std::ptrdiff_t>(length));
  return text;
}

TEST(MetricsEndpoint, ServesMetricsOnLoopbackAnd404ForAnythingElse) {
  LoopThread loop;
  int scrapes = 0;
  MetricsEndpointOptions options;
  options.port = 0;
  MetricsEndpoint endpoint(loop.io.get_executor(), options, [&] {
    ++scrapes;
    return std::string("canbridge_backbone_peers_up 1\n");
  });
  endpoint.start();
  ASSERT_NE(endpoint.port(), 0);
  loop.run();

  asio::io_context client;
  tcp::socket socket(client);
  socket.connect({asio::ip::make_address("127.0.0.1"), endpoint.port()});
  const std::string ok = exchange(socket, "GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(ok.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << ok;
  EXPECT_NE(ok.find("Content-Type: text/plain; version=0.0.4; charset=utf-8\r\n"),
            std::string::npos)
      << ok;
  EXPECT_NE(ok.find("\r\n\r\ncanbridge_backbone_peers_up 1\n"), std::string::npos) << ok;
  // The same connection (keep-alive): one request after the other.
  const std::string missing = exchange(socket, "GET /other HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(missing.rfind("HTTP/1.1 404 Not Found\r\n", 0), 0u) << missing;
  const std::string post =
      exchange(socket, "POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n");
  EXPECT_EQ(post.rfind("HTTP/1.1 404 Not Found\r\n", 0), 0u) << post;
  const std::string again = exchange(socket, "GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(again.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << again;
  loop.stop([&] { endpoint.stop(); });
  EXPECT_EQ(scrapes, 2);
}

TEST(MetricsEndpoint, ConnectionsAreBoundedAndIdleOnesClosed) {
  LoopThread loop;
  MetricsEndpointOptions options;
  options.port = 0;
  options.max_connections = 1;
  options.read_timeout = 300ms;
  MetricsEndpoint endpoint(loop.io.get_executor(), options, [] { return std::string("x 1\n"); });
  endpoint.start();
  loop.run();
  asio::io_context client;
  const tcp::endpoint where{asio::ip::make_address("127.0.0.1"), endpoint.port()};
  tcp::socket idle(client);
  idle.connect(where);
  // The first connection holds the only slot (it sends nothing); a second is closed at once.
  // (The first must have been accepted first: a request on it proves it.)
  EXPECT_EQ(exchange(idle, "GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n").rfind("HTTP/1.1 200", 0),
            0u);
  tcp::socket second(client);
  second.connect(where);
  boost::system::error_code ec;
  asio::write(second, asio::buffer(std::string("GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")), ec);
  char byte = 0;
  asio::read(second, asio::buffer(&byte, 1), ec);
  EXPECT_TRUE(ec == asio::error::eof || ec == asio::error::connection_reset) << ec.message();
  // The idle one is closed after read_timeout without a request: the read ends with eof.
  const auto before = std::chrono::steady_clock::now();
  asio::read(idle, asio::buffer(&byte, 1), ec);
  EXPECT_TRUE(ec == asio::error::eof || ec == asio::error::connection_reset) << ec.message();
  EXPECT_LT(std::chrono::steady_clock::now() - before, 5s);
  loop.stop([&] { endpoint.stop(); });
}

TEST(MetricsEndpoint, RefusesANonLoopbackAddress) {
  asio::io_context io;
  MetricsEndpointOptions options;
  options.address = "0.0.0.0";
  MetricsEndpoint endpoint(io.get_executor(), options, [] { return std::string(); });
  try {
    endpoint.start();
    FAIL() << "0.0.0.0 accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("not a loopback address"), std::string::npos) << e.what();
  }
}

TEST(StatsEndpoint, AnswersStatsAsOneJsonLineThenOkAndRefusesOtherCommands) {
  char dir_template[] = "/tmp/canbridge-stats-XXXXXX";
  ASSERT_NE(::mkdtemp(dir_template), nullptr);
  const std::string path = std::string(dir_template) + "/gateway.sock";
  LoopThread loop;
  StatsEndpoint endpoint(loop.io.get_executor(), {path}, [] { return std::string("{\"a\":1}"); });
  endpoint.start();
  loop.run();
  asio::io_context client;
  asio::local::stream_protocol::socket socket(client);
  socket.connect(asio::local::stream_protocol::endpoint(path));
  asio::write(socket,
              asio::buffer(std::string("[7] stats\n[8] 0 nodes\n# a comment\n[9] stats\n")));
  asio::streambuf buffer;
  asio::read_until(socket, buffer, "[9] OK\r\n");
  const std::string all(asio::buffers_begin(buffer.data()), asio::buffers_end(buffer.data()));
  EXPECT_EQ(all.rfind("[7] {\"a\":1}\r\n[7] OK\r\n[8] ERROR:100", 0), 0u) << all;
  EXPECT_NE(all.find("[9] {\"a\":1}\r\n[9] OK\r\n"), std::string::npos) << all;
  loop.stop([&] { endpoint.stop(); });
  EXPECT_FALSE(std::filesystem::exists(path));  // stop() removes the socket file it made
  std::filesystem::remove(dir_template);
}

}  // namespace
}  // namespace canbridge::bridge
