// The backbone session through canbridge-link-emulator, over TCP and over a pty pair: a bit error
// rate of 1e-4 and ten random cuts, while 100,000 reliable messages cross one way and 20,000 the
// other. Every message must arrive exactly once, in order, bit-exact.
#include <gtest/gtest.h>
#include <unistd.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <filesystem>
#include <functional>

#include "backbone/serial_client.hpp"
#include "backbone/session.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "tests/backbone/session_peers.hpp"
#include "tests/support/event_loop.hpp"
#include "tests/support/process.hpp"
#include "tests/support/spawn_checked.hpp"
#include "tools/link_emulator/command_line.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::exactly_once_in_order;
using testing::SessionEnd;

constexpr std::uint64_t kUpstream = 100000;   // gateway -> surface
constexpr std::uint64_t kDownstream = 20000;  // surface -> gateway

// Messages are produced at a steady pace over this long, so that the ten cuts (scheduled by the
// emulator between 0.5 s and 6.5 s, 150-250 ms each) all fall inside the transfer.
constexpr auto kProductionTime = 7s;

SessionOptions lossy_line_options() {
  SessionOptions o;
  o.keepalive_interval = 25ms;
  o.dead_after = 100ms;  // cuts last 150 ms or more, so each one is noticed
  o.retransmit_timeout = 100ms;
  // About one message in 60 is hit at 1e-4; selective repeat resends only those, and the
  // receiver keeps what follows a hole in a reorder buffer as large as this window.
  o.resend_buffer_messages = 64;
  o.resend_buffer_bytes = 16 * 1024;
  o.max_write_bytes = 1024;
  return o;
}

std::vector<std::string> emulator_args(std::string a, std::string b) {
  return {CANBRIDGE_LINK_EMULATOR_BIN,
          "--a",
          std::move(a),
          "--b",
          std::move(b),
          "--baud",
          "10000000",
          "--ber",
          "1e-4",
          "--seed",
          "20261128",
          "--cuts",
          "10",
          "--cut-ms",
          "150:250",
          "--cut-window-s",
          "0.5:6.5"};
}

// Raises both ends' production limits in small steps until the totals, over kProductionTime.
asio::awaitable<void> pace(SessionEnd& gateway, SessionEnd& surface) {
  asio::steady_timer timer(co_await asio::this_coro::executor);
  const auto started = std::chrono::steady_clock::now();
  for (double share = 0; share < 1.0;) {
    share =
        std::min(1.0, std::chrono::duration<double>(std::chrono::steady_clock::now() - started) /
                          kProductionTime);
    gateway.send_up_to(static_cast<std::uint64_t>(share * kUpstream));
    surface.send_up_to(static_cast<std::uint64_t>(share * kDownstream));
    timer.expires_after(20ms);
    co_await timer.async_wait(asio::use_awaitable);
  }
}

// Runs both ends until everything arrived (or 60 s pass), then checks the result.
void expect_everything_delivered(asio::io_context& io, SessionEnd& gateway, SessionEnd& surface,
                                 test::ChildProcess& emulator) {
  gateway.payload_size = surface.payload_size = 16;
  test::spawn_checked(io, pace(gateway, surface));
  const bool done = test::run_until(
      io,
      [&] {
        return surface.received.size() >= kUpstream && gateway.received.size() >= kDownstream;
      },
      60s);
  const std::string emulated = emulator.output();
  ASSERT_TRUE(done) << "upstream " << surface.received.size() << "/" << kUpstream << ", downstream "
                    << gateway.received.size() << "/" << kDownstream << "\n"
                    << emulated;
  EXPECT_TRUE(exactly_once_in_order(surface.received, kUpstream));
  EXPECT_TRUE(exactly_once_in_order(gateway.received, kDownstream));
  EXPECT_EQ(surface.corrupt + gateway.corrupt, 0u);
  // The conditions really were hostile while the messages crossed: all ten cuts happened, each
  // side saw links die and come back, and payloads had to be resent.
  EXPECT_NE(emulated.find("cut 10/10 ends"), std::string::npos) << emulated;
  EXPECT_GE(surface.ups, 5);
  EXPECT_GT(gateway.counters.reliable_resent, 0u);
  EXPECT_GT(surface.counters.resend_requests + gateway.counters.resend_requests, 0u);
  std::printf("upstream resent %llu, downstream resent %llu, links %d, dead links %llu/%llu\n",
              static_cast<unsigned long long>(gateway.counters.reliable_resent),
              static_cast<unsigned long long>(surface.counters.reliable_resent), surface.ups,
              static_cast<unsigned long long>(gateway.counters.dead_links),
              static_cast<unsigned long long>(surface.counters.dead_links));
}

TEST(EmulatedSession, TcpThroughANoisyLineWithTenCuts) {
  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, lossy_line_options(), {1}};
  SessionEnd surface{"surface", v1::Hello::ROLE_SURFACE, lossy_line_options()};

  // TCP does not corrupt, but the emulated line under it does: CRC framing on this link.
  ServerOptions server_options;
  server_options.link.framing = LinkFraming::cobs_crc32c;
  auto server = TcpServer::create(io.get_executor(), server_options);
  ASSERT_FALSE(server->start("127.0.0.1", 0, [&](auto link) { surface.attach(link); }));
  test::ChildProcess emulator(emulator_args(
      "tcp-listen:127.0.0.1:0", "tcp-connect:127.0.0.1:" + std::to_string(server->port())));
  ASSERT_TRUE(emulator.wait_for_line("link-emulator: ready", 5s)) << emulator.output();
  const auto ready = emulator::find_ready_line(emulator.output());
  ASSERT_TRUE(ready);
  const auto port = emulator::endpoint_port(ready->a);
  ASSERT_TRUE(port);

  ClientOptions client_options;
  client_options.backoff_min = 20ms;
  client_options.backoff_max = 200ms;
  client_options.link.framing = LinkFraming::cobs_crc32c;
  auto client = TcpClient::create(io.get_executor(), "127.0.0.1", *port, client_options);
  client->start([&](auto link) { gateway.attach(link); });

  expect_everything_delivered(io, gateway, surface, emulator);
  client->stop();
  server->stop();
  io.restart();
  io.run_for(50ms);
  EXPECT_EQ(emulator.stop(), 0);
}

TEST(EmulatedSession, SerialPtyPairThroughANoisyLineWithTenCuts) {
  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, lossy_line_options(), {1}};
  SessionEnd surface{"surface", v1::Hello::ROLE_SURFACE, lossy_line_options()};

  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("canbridge-session-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  test::ChildProcess emulator(
      emulator_args("pty:" + (dir / "gw").string(), "pty:" + (dir / "surface").string()));
  ASSERT_TRUE(emulator.wait_for_line("link-emulator: ready", 5s)) << emulator.output();

  auto line = [&](const std::string& name) {
    SerialOptions o;
    o.device = (dir / name).string();
    o.baud = 115200;  // a pty ignores the rate; the emulator imposes the line's
    o.backoff_min = 20ms;
    o.backoff_max = 200ms;
    return SerialClient::create(io.get_executor(), o);
  };
  auto gateway_line = line("gw");
  auto surface_line = line("surface");
  gateway_line->start([&](auto link) { gateway.attach(link); });
  surface_line->start([&](auto link) { surface.attach(link); });

  expect_everything_delivered(io, gateway, surface, emulator);
  std::uint64_t crc_errors = 0;
  for (auto& l : surface.links) crc_errors += l->message_link()->counters().deframer.crc_errors;
  for (auto& l : gateway.links) crc_errors += l->message_link()->counters().deframer.crc_errors;
  EXPECT_GT(crc_errors, 0u);  // bit errors were caught by the CRC, not delivered
  gateway_line->stop();
  surface_line->stop();
  io.restart();
  io.run_for(50ms);
  EXPECT_EQ(emulator.stop(), 0);
  std::filesystem::remove_all(dir);
}

// Process data is never resent, so what a noisy line loses of it is gone; it must not be gone
// without a count. Every unreliable payload up to the highest that arrived either arrived or is
// counted as lost on the line (bit errors caught by the CRC, writes lost in cuts).
TEST(EmulatedSession, UnreliablePayloadsLostOnTheLineAreCounted) {
  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, lossy_line_options(), {1}};
  SessionEnd surface{"surface", v1::Hello::ROLE_SURFACE, lossy_line_options()};
  gateway.payload_size = 16;
  ServerOptions server_options;
  server_options.link.framing = LinkFraming::cobs_crc32c;
  auto server = TcpServer::create(io.get_executor(), server_options);
  ASSERT_FALSE(server->start("127.0.0.1", 0, [&](auto link) { surface.attach(link); }));
  test::ChildProcess emulator({CANBRIDGE_LINK_EMULATOR_BIN, "--a", "tcp-listen:127.0.0.1:0", "--b",
                               "tcp-connect:127.0.0.1:" + std::to_string(server->port()), "--baud",
                               "10000000", "--ber", "1e-4", "--seed", "20261201", "--cuts", "2",
                               "--cut-ms", "150:250", "--cut-window-s", "0.3:1.5"});
  ASSERT_TRUE(emulator.wait_for_line("link-emulator: ready", 5s)) << emulator.output();
  const auto ready = emulator::find_ready_line(emulator.output());
  ASSERT_TRUE(ready);
  const auto port = emulator::endpoint_port(ready->a);
  ASSERT_TRUE(port);
  ClientOptions client_options;
  client_options.backoff_min = 20ms;
  client_options.backoff_max = 200ms;
  client_options.link.framing = LinkFraming::cobs_crc32c;
  auto client = TcpClient::create(io.get_executor(), "127.0.0.1", *port, client_options);
  client->start([&](auto link) { gateway.attach(link); });

  // 10 payloads every 2 ms for about 2 s, and on until one numbered past 10,000 arrived.
  constexpr std::uint64_t kWanted = 10000;
  asio::steady_timer pace(io);
  std::uint64_t limit = 0;
  std::function<void()> more = [&] {
    gateway.send_unreliable_up_to(limit += 10);
    pace.expires_after(2ms);
    pace.async_wait([&](boost::system::error_code ec) {
      if (!ec) more();
    });
  };
  more();
  const bool done = test::run_until(
      io, [&] { return surface.highest_unreliable >= kWanted; }, 30s);
  pace.cancel();
  ASSERT_TRUE(done) << "highest " << surface.highest_unreliable << "\n" << emulator.output();
  const SessionCounters& c = surface.counters;
  EXPECT_EQ(surface.unreliable, c.unreliable_delivered);
  EXPECT_EQ(c.unreliable_delivered + c.unreliable_lost, surface.highest_unreliable);
  EXPECT_GT(c.unreliable_lost, 0u);  // the line really lost some
  std::printf("unreliable: highest %llu, delivered %llu, counted lost on the line %llu\n",
              static_cast<unsigned long long>(surface.highest_unreliable),
              static_cast<unsigned long long>(c.unreliable_delivered),
              static_cast<unsigned long long>(c.unreliable_lost));
  client->stop();
  server->stop();
  io.restart();
  io.run_for(50ms);
  EXPECT_EQ(emulator.stop(), 0);
}

}  // namespace
}  // namespace canbridge::backbone
