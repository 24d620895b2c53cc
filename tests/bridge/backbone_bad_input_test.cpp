// Bad input on the backbone, in process over real loopback TCP: a raw socket plays the peer and
// writes bytes the roles must survive (counted, logged once, link dropped only when the stream
// itself is unrecoverable).
#include <gtest/gtest.h>

#include <boost/asio/co_spawn.hpp>
#include <boost/asio/connect.hpp>
#include <boost/asio/detached.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/write.hpp>
#include <functional>

#include "backbone/delimited_codec.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;

using test::run_until;

// Receives one batch on `bus`, running the loop until it arrives (bounded).
std::vector<can::Frame> receive_one_batch(asio::io_context& io, can::Bus& bus) {
  std::vector<can::Frame> frames;
  bool done = false;
  asio::co_spawn(
      io,
      [&]() -> asio::awaitable<void> {
        co_await bus.receive_batch(frames);
        done = true;
      },
      asio::detached);
  EXPECT_TRUE(run_until(io, [&] { return done; }));
  return frames;
}

std::string delimited(const v1::Envelope& e) {
  std::string out;
  backbone::append_message(out, e);
  return out;
}

v1::Envelope hello(v1::Hello::Role role, std::uint32_t major, std::vector<std::uint32_t> modules) {
  v1::Envelope e;
  e.mutable_hello()->set_protocol_major(major);
  e.mutable_hello()->set_role(role);
  e.mutable_hello()->set_name("raw-peer");
  for (auto m : modules) e.mutable_hello()->add_module_ids(m);
  return e;
}

v1::Envelope frames(std::uint32_t module, std::initializer_list<can::Frame> list) {
  v1::Envelope e;
  FrameBatchBuilder b;
  b.start(*e.mutable_frames(), module);
  for (const auto& f : list) b.append(*e.mutable_frames(), f);
  return e;
}

// A surface on a virtual bus with a TcpServer, and a raw TCP socket connected to it.
class SurfaceBadInput : public ::testing::Test {
 protected:
  SurfaceBadInput()
      : medium(io.get_executor(), "surface-bus"),
        observer(medium.connect("observer")),
        surface(io.get_executor(), "surface", medium.connect("surface")),
        server(backbone::TcpServer::create(io.get_executor())) {
    surface.start();
    EXPECT_FALSE(server->start("127.0.0.1", 0, [this](auto link) { surface.attach(link); }));
  }
  ~SurfaceBadInput() override {
    surface.stop();
    server->stop();
    io.run_for(100ms);
  }
  tcp::socket connect() {
    tcp::socket s(io);
    s.connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), server->port()));
    return s;
  }
  void send(tcp::socket& s, const std::string& bytes) { asio::write(s, asio::buffer(bytes)); }
  bool peer_closed(tcp::socket& s) {
    // Reading to EOF proves the surface dropped us (whatever it sent before, e.g. its hello).
    s.non_blocking(true);
    return run_until(io, [&] {
      char buf[256];
      boost::system::error_code ec;
      s.read_some(asio::buffer(buf), ec);
      return ec == asio::error::eof || ec == asio::error::connection_reset;
    });
  }
  asio::io_context io{1};
  can::VirtualBus medium;
  std::unique_ptr<can::Bus> observer;
  Surface surface;
  std::shared_ptr<backbone::TcpServer> server;
};

TEST_F(SurfaceBadInput, RecoverableGarbageIsCountedAndTheLinkStaysUp) {
  tcp::socket s = connect();
  send(s, delimited(hello(v1::Hello::ROLE_GATEWAY, kProtocolMajor, {1})));
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));

  std::string not_an_envelope;
  backbone::append_delimited(not_an_envelope,
                             std::vector<std::uint8_t>{0x0A, 0xFF, 0xFF, 0xFF, 0x7F});
  send(s, not_an_envelope);
  v1::Envelope bad_columns = frames(1, {can::Frame::standard(0x181, {1})});
  bad_columns.mutable_frames()->add_can_id(0x182);  // an id with no length byte
  send(s, delimited(bad_columns));
  send(s, delimited(frames(9, {can::Frame::standard(0x181, {2})})));  // never announced
  send(s, delimited(frames(1, {can::Frame::standard(0x1A1, {3})})));

  const std::vector<can::Frame> seen = receive_one_batch(io, *observer);
  ASSERT_EQ(seen.size(), 1u);
  EXPECT_EQ(seen[0], can::Frame::standard(0x1A1, {3}));
  const SurfaceCounters c = surface.counters();
  EXPECT_EQ(c.backbone.malformed_envelopes, 1u);
  EXPECT_EQ(c.backbone.malformed_batches, 1u);
  EXPECT_EQ(c.backbone.unknown_module, 1u);
  EXPECT_EQ(surface.gateways_ready(), 1u);
}

TEST_F(SurfaceBadInput, UnrecoverableStreamDropsOnlyThatLink) {
  tcp::socket s = connect();
  send(s, delimited(hello(v1::Hello::ROLE_GATEWAY, kProtocolMajor, {1})));
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));
  send(s, std::string(6, '\xFF'));  // a length prefix longer than any varint32
  EXPECT_TRUE(peer_closed(s));
  EXPECT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 0; }));

  tcp::socket again = connect();  // the surface still serves
  send(again, delimited(hello(v1::Hello::ROLE_GATEWAY, kProtocolMajor, {1})));
  EXPECT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));

  std::string oversize;
  oversize.push_back('\x80');  // varint 0x80 0x80 0x80 0x01 = 2 MiB > 1 MiB limit
  oversize += std::string("\x80\x80\x01", 3);
  send(again, oversize);
  EXPECT_TRUE(peer_closed(again));
}

TEST_F(SurfaceBadInput, DataBeforeHelloAndWrongVersionOrRoleAreRefused) {
  tcp::socket early = connect();
  send(early, delimited(frames(1, {can::Frame::standard(0x181, {1})})));
  EXPECT_TRUE(peer_closed(early));
  tcp::socket future = connect();
  send(future, delimited(hello(v1::Hello::ROLE_GATEWAY, kProtocolMajor + 1, {1})));
  EXPECT_TRUE(peer_closed(future));
  tcp::socket twin = connect();
  send(twin, delimited(hello(v1::Hello::ROLE_SURFACE, kProtocolMajor, {})));
  EXPECT_TRUE(peer_closed(twin));
  EXPECT_EQ(surface.counters().backbone.protocol_errors, 3u);
  EXPECT_EQ(surface.gateways_ready(), 0u);
}

TEST(GatewayBadInput, GarbageFromTheSurfaceDropsTheLinkAndTheGatewayReconnects) {
  asio::io_context io{1};
  can::VirtualBus bus(io.get_executor(), "module-bus");
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());
  std::vector<GatewayModule> modules;
  modules.push_back({1, bus.connect("gateway")});
  auto node = bus.connect("node");
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules));
  gateway.start();

  tcp::acceptor acceptor(io, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  backbone::ClientOptions options;
  options.backoff_min = 10ms;
  auto client = backbone::TcpClient::create(io.get_executor(), "127.0.0.1",
                                            acceptor.local_endpoint().port(), options);
  client->start([&](auto link) { gateway.attach(link); });

  // The client connects from the loop: accept without blocking it.
  acceptor.non_blocking(true);
  auto accept = [&](tcp::socket& socket) {
    return run_until(io, [&] {
      boost::system::error_code ec;
      acceptor.accept(socket, ec);
      return !ec;
    });
  };
  tcp::socket first(io);
  ASSERT_TRUE(accept(first));
  asio::write(first, asio::buffer(delimited(hello(v1::Hello::ROLE_SURFACE, 1, {}))));
  ASSERT_TRUE(run_until(io, [&] { return gateway.connected(); }));
  // A surface frame for surface node 40 = module 1 node 8 reaches the module bus as 0x608.
  asio::write(first,
              asio::buffer(delimited(frames(kAnyModule, {can::Frame::standard(0x628, {7})}))));
  const std::vector<can::Frame> at_node = receive_one_batch(io, *node);
  EXPECT_EQ(at_node.at(0), can::Frame::standard(0x608, {7}));

  asio::write(first, asio::buffer(std::string(6, '\xFF')));
  ASSERT_TRUE(run_until(io, [&] { return !gateway.connected(); }));
  tcp::socket second(io);
  ASSERT_TRUE(accept(second));
  EXPECT_TRUE(run_until(io, [&] { return client->counters().connects == 2; }));
  client->stop();
  gateway.stop();
  io.run_for(100ms);
}

}  // namespace
}  // namespace canbridge::bridge
