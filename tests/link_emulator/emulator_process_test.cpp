// canbridge-link-emulator as a program: between TCP peers and ptys of the test, waiting on its
// lines and on bytes arriving, never on fixed sleeps.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/serial_port.hpp>
#include <boost/asio/write.hpp>
#include <chrono>
#include <filesystem>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "tests/support/event_loop.hpp"
#include "tests/support/process.hpp"
#include "tools/link_emulator/command_line.hpp"

namespace canbridge::emulator {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;
using test::ChildProcess;
using test::run_until;

const std::string kEmulator = CANBRIDGE_LINK_EMULATOR_BIN;

std::optional<ReadyLine> wait_ready(ChildProcess& emulator) {
  if (!emulator.wait_for_line("link-emulator: ready", 20s)) return std::nullopt;
  return find_ready_line(emulator.output());
}

std::string payload(std::size_t size, std::uint32_t seed) {
  std::mt19937 engine(seed);
  std::string bytes(size, '\0');
  for (char& byte : bytes) byte = static_cast<char>(engine());
  return bytes;
}

struct PendingRead {
  std::string data;
  std::optional<boost::system::error_code> result;
  bool done() const { return result.has_value(); }
};

// Reads exactly `size` bytes in the background (or until an error).
template <typename Stream>
void start_read(Stream& stream, PendingRead& read, std::size_t size) {
  read.data.assign(size, '\0');
  read.result.reset();
  asio::async_read(stream, asio::buffer(read.data),
                   [&read](boost::system::error_code ec, std::size_t n) {
                     read.data.resize(n);
                     read.result = ec;
                   });
}

struct PendingWrite {
  std::optional<boost::system::error_code> result;
  bool done() const { return result.has_value(); }
};

template <typename Stream>
void start_write(Stream& stream, const std::string& data, PendingWrite& write) {
  write.result.reset();
  asio::async_write(stream, asio::buffer(data),
                    [&write](boost::system::error_code ec, std::size_t) { write.result = ec; });
}

struct PendingAccept {
  std::optional<tcp::socket> socket;
  std::optional<boost::system::error_code> result;
  bool done() const { return result.has_value(); }
};

void start_accept(tcp::acceptor& acceptor, PendingAccept& accept) {
  accept.result.reset();
  acceptor.async_accept([&accept](boost::system::error_code ec, tcp::socket socket) {
    accept.socket.emplace(std::move(socket));
    accept.result = ec;
  });
}

tcp::endpoint loopback(std::uint16_t port) {
  return tcp::endpoint(asio::ip::address_v4::loopback(), port);
}

// Sends `left` through x and `right` through y at the same time and checks both arrive intact.
template <typename X, typename Y>
void exchange(asio::io_context& io, X& x, Y& y, const std::string& left, const std::string& right) {
  PendingWrite x_write;
  PendingWrite y_write;
  PendingRead x_read;
  PendingRead y_read;
  start_write(x, left, x_write);
  start_write(y, right, y_write);
  start_read(y, y_read, left.size());
  start_read(x, x_read, right.size());
  ASSERT_TRUE(run_until(
      io, [&] { return x_write.done() && y_write.done() && x_read.done() && y_read.done(); }, 20s));
  EXPECT_FALSE(*x_write.result) << x_write.result->message();
  EXPECT_FALSE(*y_write.result) << y_write.result->message();
  EXPECT_FALSE(*y_read.result) << y_read.result->message();
  EXPECT_FALSE(*x_read.result) << x_read.result->message();
  EXPECT_TRUE(y_read.data == left) << "x -> y bytes differ";
  EXPECT_TRUE(x_read.data == right) << "y -> x bytes differ";
}

// True when the connection ends (EOF or reset) within the timeout.
bool closes(asio::io_context& io, tcp::socket& socket) {
  PendingRead read;
  start_read(socket, read, 1);
  if (!run_until(
          io, [&] { return read.done(); }, 10s))
    return false;
  return static_cast<bool>(*read.result);
}

class TempDir {
 public:
  TempDir() {
    std::string pattern = "/tmp/link-emulator-test-XXXXXX";
    if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  std::string operator/(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

bool output_has(const ChildProcess& child, const std::string& text) {
  return child.output().find(text) != std::string::npos;
}

// The gateway's side (A, listening) and the surface's side (B, the emulator connects to it).
class TcpLink : public ::testing::Test {
 protected:
  void start(std::vector<std::string> options) {
    std::vector<std::string> argv{
        kEmulator, "--a", "tcp-listen:127.0.0.1:0", "--b",
        "tcp-connect:127.0.0.1:" + std::to_string(surface_.local_endpoint().port())};
    argv.insert(argv.end(), options.begin(), options.end());
    emulator_.emplace(argv);
    const auto ready = wait_ready(*emulator_);
    ASSERT_TRUE(ready) << emulator_->output();
    ASSERT_TRUE(endpoint_port(ready->a));
    gateway_port_ = *endpoint_port(ready->a);
    EXPECT_EQ(ready->b,
              "tcp-connect:127.0.0.1:" + std::to_string(surface_.local_endpoint().port()));
  }

  // A gateway connection and the surface connection the emulator opens for it.
  void connect(tcp::socket& gateway, std::optional<tcp::socket>& surface) {
    PendingAccept accepted;
    start_accept(surface_, accepted);
    boost::system::error_code ec;
    gateway.connect(loopback(gateway_port_), ec);
    ASSERT_FALSE(ec) << ec.message();
    ASSERT_TRUE(run_until(
        io_, [&] { return accepted.done(); }, 10s));
    ASSERT_FALSE(*accepted.result) << accepted.result->message();
    surface = std::move(accepted.socket);
  }

  // A connected pair that has exchanged bytes, once the emulator's one silent cut has begun.
  void connect_then_wait_for_silent_cut(tcp::socket& gateway, std::optional<tcp::socket>& surface) {
    ASSERT_NO_FATAL_FAILURE(start({"--cut-at", "1.5+1.5", "--cut-mode", "silent"}));
    ASSERT_NO_FATAL_FAILURE(connect(gateway, surface));
    exchange(io_, gateway, *surface, "ping", "pong");
    ASSERT_TRUE(emulator_->wait_for_line("link-emulator: cut 1/1 begins (silent)", 10s));
  }

  // `read` stays pending while the cut lasts (a bounded wait for an event that must not come),
  // then completes once it has ended.
  void expect_held_until_the_cut_ends(PendingRead& read) {
    EXPECT_FALSE(run_until(
        io_, [&] { return read.done(); }, 500ms));
    EXPECT_FALSE(output_has(*emulator_, "cut 1/1 ends")) << "the cut ended before the check";
    ASSERT_TRUE(emulator_->wait_for_line("link-emulator: cut 1/1 ends", 10s));
    ASSERT_TRUE(run_until(
        io_, [&] { return read.done(); }, 10s));
    EXPECT_FALSE(*read.result) << read.result->message();
  }

  asio::io_context io_;
  tcp::acceptor surface_{io_, loopback(0)};
  std::optional<ChildProcess> emulator_;
  std::uint16_t gateway_port_ = 0;
};

TEST_F(TcpLink, BytesArriveIntactBothWays) {
  ASSERT_NO_FATAL_FAILURE(start({}));
  tcp::socket gateway(io_);
  std::optional<tcp::socket> surface;
  ASSERT_NO_FATAL_FAILURE(connect(gateway, surface));
  exchange(io_, gateway, *surface, payload(256 * 1024, 1), payload(256 * 1024, 2));
  EXPECT_EQ(emulator_->stop(), 0);
  EXPECT_TRUE(output_has(*emulator_, "final stats a->b in=262144 out=262144 flipped=0"))
      << emulator_->output();
  EXPECT_TRUE(output_has(*emulator_, "b->a in=262144 out=262144 flipped=0"));
}

TEST_F(TcpLink, LatencyAndBandwidthDelayDelivery) {
  // 5000 bytes x 10 bits at 100 kbit/s: 500 ms on the line, plus 150 ms latency.
  ASSERT_NO_FATAL_FAILURE(start({"--baud", "100000", "--latency-ms", "150"}));
  tcp::socket gateway(io_);
  std::optional<tcp::socket> surface;
  ASSERT_NO_FATAL_FAILURE(connect(gateway, surface));
  const std::string data = payload(5000, 3);
  const auto sent = std::chrono::steady_clock::now();
  PendingWrite write;
  PendingRead read;
  start_write(gateway, data, write);
  start_read(*surface, read, data.size());
  ASSERT_TRUE(run_until(
      io_, [&] { return read.done(); }, 20s));
  EXPECT_GE(std::chrono::steady_clock::now() - sent, 650ms);
  EXPECT_TRUE(read.data == data);
}

TEST_F(TcpLink, NewGatewayConnectionReplacesTheOld) {
  ASSERT_NO_FATAL_FAILURE(start({}));
  tcp::socket first(io_);
  std::optional<tcp::socket> first_surface;
  ASSERT_NO_FATAL_FAILURE(connect(first, first_surface));
  tcp::socket second(io_);
  std::optional<tcp::socket> second_surface;
  ASSERT_NO_FATAL_FAILURE(connect(second, second_surface));
  EXPECT_TRUE(closes(io_, first));
  EXPECT_TRUE(closes(io_, *first_surface));
  exchange(io_, second, *second_surface, payload(1000, 4), payload(1000, 5));
}

TEST_F(TcpLink, CutClosesConnectionsAndRefusesNewOnesUntilItEnds) {
  ASSERT_NO_FATAL_FAILURE(start({"--cut-at", "1.5+2"}));
  tcp::socket gateway(io_);
  std::optional<tcp::socket> surface;
  ASSERT_NO_FATAL_FAILURE(connect(gateway, surface));
  exchange(io_, gateway, *surface, "ping", "pong");

  ASSERT_TRUE(emulator_->wait_for_line("link-emulator: cut 1/1 begins", 10s));
  EXPECT_TRUE(closes(io_, gateway));
  EXPECT_TRUE(closes(io_, *surface));
  tcp::socket during_cut(io_);
  boost::system::error_code ec;
  during_cut.connect(loopback(gateway_port_), ec);
  if (!ec) {
    EXPECT_TRUE(closes(io_, during_cut));  // accepted and closed at once
  }
  EXPECT_FALSE(output_has(*emulator_, "cut 1/1 ends")) << "the cut ended before the check";

  ASSERT_TRUE(emulator_->wait_for_line("link-emulator: cut 1/1 ends", 10s));
  tcp::socket after(io_);
  std::optional<tcp::socket> after_surface;
  ASSERT_NO_FATAL_FAILURE(connect(after, after_surface));
  exchange(io_, after, *after_surface, payload(1000, 6), payload(1000, 7));
  EXPECT_EQ(emulator_->stop(), 0);
}

// A silent cut (a blackholed route): the connections stay open, nothing moves, and what was sent
// during the cut arrives after it. Fails if the cut closes the connections (close mode) or
// discards the bytes.
TEST_F(TcpLink, SilentCutHoldsConnectionsAndDeliversAfterIt) {
  tcp::socket gateway(io_);
  std::optional<tcp::socket> surface;
  ASSERT_NO_FATAL_FAILURE(connect_then_wait_for_silent_cut(gateway, surface));
  const std::string during = payload(3000, 8);
  PendingWrite write;
  PendingRead read;
  start_write(gateway, during, write);
  start_read(*surface, read, during.size());
  ASSERT_NO_FATAL_FAILURE(expect_held_until_the_cut_ends(read));
  EXPECT_TRUE(read.data == during) << "bytes sent during the silent cut were not delivered";
  exchange(io_, gateway, *surface, payload(1000, 9), payload(1000, 10));  // the same connections
  EXPECT_EQ(emulator_->stop(), 0);
}

// An end that gives up during a silent cut: the other end learns of it only after the cut, and
// after the bytes sent before the close (as TCP delivers data before its FIN).
TEST_F(TcpLink, CloseDuringSilentCutReachesThePeerAfterItsBytes) {
  tcp::socket gateway(io_);
  std::optional<tcp::socket> surface;
  ASSERT_NO_FATAL_FAILURE(connect_then_wait_for_silent_cut(gateway, surface));
  const std::string last = payload(500, 11);
  boost::system::error_code ec;
  asio::write(gateway, asio::buffer(last), ec);
  ASSERT_FALSE(ec) << ec.message();
  gateway.close();
  PendingRead read;
  start_read(*surface, read, last.size());
  ASSERT_NO_FATAL_FAILURE(expect_held_until_the_cut_ends(read));
  EXPECT_TRUE(read.data == last);
  EXPECT_TRUE(closes(io_, *surface));
  EXPECT_EQ(emulator_->stop(), 0);
}

TEST(PtyLink, BytesFlowBothWaysAndSurviveTheClientReopening) {
  TempDir dir;
  const std::string gw_path = dir / "gw";
  const std::string surface_path = dir / "surface";
  ChildProcess emulator({kEmulator, "--a", "pty:" + gw_path, "--b", "pty:" + surface_path});
  const auto ready = wait_ready(emulator);
  ASSERT_TRUE(ready) << emulator.output();
  const auto gw_device = endpoint_pty_device(ready->a);
  ASSERT_TRUE(gw_device) << ready->a;
  EXPECT_EQ(ready->a, "pty:" + gw_path + "->" + *gw_device);
  EXPECT_EQ(std::filesystem::read_symlink(gw_path).string(), *gw_device);

  asio::io_context io;
  asio::serial_port gw(io, gw_path);
  asio::serial_port surface(io, surface_path);
  exchange(io, gw, surface, payload(64 * 1024, 8), payload(64 * 1024, 9));

  // The emulator keeps the slave open itself, so a client closing it does not break the master.
  gw.close();
  gw.open(gw_path);
  exchange(io, gw, surface, payload(1000, 10), payload(1000, 11));

  EXPECT_EQ(emulator.stop(), 0);
  EXPECT_TRUE(output_has(emulator, "final stats a->b in=66536 out=66536")) << emulator.output();
  EXPECT_FALSE(std::filesystem::exists(std::filesystem::symlink_status(gw_path)));
  EXPECT_FALSE(std::filesystem::exists(std::filesystem::symlink_status(surface_path)));
}

TEST(PtyLink, CutDiscardsBytesBothWays) {
  TempDir dir;
  ChildProcess emulator({kEmulator, "--a", "pty:" + dir / "gw", "--b", "pty:" + dir / "surface",
                         "--cut-at", "0.5+1"});
  ASSERT_TRUE(wait_ready(emulator)) << emulator.output();
  asio::io_context io;
  asio::serial_port gw(io, dir / "gw");
  asio::serial_port surface(io, dir / "surface");

  ASSERT_TRUE(emulator.wait_for_line("link-emulator: cut 1/1 begins", 10s));
  const std::string lost_down = payload(300, 12);
  const std::string lost_up = payload(200, 13);
  asio::write(gw, asio::buffer(lost_down));
  asio::write(surface, asio::buffer(lost_up));
  ASSERT_TRUE(emulator.wait_for_line("link-emulator: cut 1/1 ends", 10s));
  // Only what was sent after the cut arrives; anything from during the cut would come first.
  exchange(io, gw, surface, "after the cut", "also after");

  EXPECT_EQ(emulator.stop(), 0);
  EXPECT_TRUE(output_has(emulator, "cut_dropped=300")) << emulator.output();
  EXPECT_TRUE(output_has(emulator, "cut_dropped=200")) << emulator.output();
}

// What B receives for `sent` from A through a pty pair with bit errors under `seed`.
std::string through_noisy_ptys(const std::string& sent, const std::string& seed) {
  TempDir dir;
  ChildProcess emulator({kEmulator, "--a", "pty:" + dir / "gw", "--b", "pty:" + dir / "surface",
                         "--ber", "1e-3", "--seed", seed});
  if (!wait_ready(emulator)) {
    ADD_FAILURE() << emulator.output();
    return {};
  }
  asio::io_context io;
  asio::serial_port gw(io, dir / "gw");
  asio::serial_port surface(io, dir / "surface");
  PendingWrite write;
  PendingRead read;
  start_write(gw, sent, write);
  start_read(surface, read, sent.size());
  EXPECT_TRUE(run_until(
      io, [&] { return read.done() && write.done(); }, 20s));
  EXPECT_EQ(emulator.stop(), 0);
  return read.data;
}

TEST(PtyLink, SameSeedCorruptsTheSameBits) {
  const std::string sent = payload(20000, 14);
  const std::string first = through_noisy_ptys(sent, "21");
  ASSERT_EQ(first.size(), sent.size());
  EXPECT_TRUE(first != sent) << "1.6e5 bits at 1e-3 should see errors";
  EXPECT_TRUE(through_noisy_ptys(sent, "21") == first);
  EXPECT_TRUE(through_noisy_ptys(sent, "22") != first);
}

TEST(LinkEmulatorProgram, BadArgumentsExitWith2) {
  const auto missing = test::run({kEmulator, "--a", "tcp-listen:127.0.0.1:0"});
  EXPECT_EQ(missing.status, 2);
  EXPECT_NE(missing.output.find("--b"), std::string::npos) << missing.output;
  const auto bad_rate =
      test::run({kEmulator, "--a", "pty:/tmp/a", "--b", "pty:/tmp/b", "--ber", "1.5"});
  EXPECT_EQ(bad_rate.status, 2);
  EXPECT_NE(bad_rate.output.find("--ber"), std::string::npos) << bad_rate.output;
}

TEST(LinkEmulatorProgram, UnusableEndpointExitsWith1) {
  const auto result =
      test::run({kEmulator, "--a", "pty:/nonexistent-dir/gw", "--b", "tcp-listen:127.0.0.1:0"});
  EXPECT_EQ(result.status, 1);
  EXPECT_NE(result.output.find("/nonexistent-dir/gw"), std::string::npos) << result.output;
}

}  // namespace
}  // namespace canbridge::emulator
