// Bad input on the backbone, in process over real loopback TCP: a raw socket plays the peer (a
// gateway toward the surface, a surface toward the gateway) and writes bytes the roles must
// survive: counted, logged once, the link dropped only when the stream itself is unrecoverable or
// the peer cannot be served (then with a Refusal saying why).
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/write.hpp>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/session.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "canbridge.pb.h"
#include "session.pb.h"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;

using test::BusRecorder;
using test::drains_within;
using test::run_until;

// Raw peers never send keepalives: a generous dead-link timeout keeps the role under test from
// dropping them for silence on a slow (sanitizer) run, so every close a test sees is the one it
// provoked.
BackboneTuning patient_tuning() {
  BackboneTuning t;
  t.session.dead_after = 30s;
  return t;
}

// A raw TCP socket playing one backbone peer: writes whatever bytes a test wants and decodes what
// the role under test sends back into envelopes, without ever blocking the loop.
class RawPeer {
 public:
  explicit RawPeer(tcp::socket socket) : socket_(std::move(socket)) {}

  void send(const std::string& bytes) { asio::write(socket_, asio::buffer(bytes)); }

  // Runs the loop until `condition` holds over what has been read so far.
  bool wait(asio::io_context& io, const std::function<bool()>& condition) {
    return run_until(io, [&] {
      poll();
      return condition();
    });
  }
  // Reading to EOF proves the role dropped us (whatever it sent before is kept in `received`).
  bool closed_by_peer(asio::io_context& io) {
    return wait(io, [&] { return eof; });
  }
  // The first envelope with a hello, or null.
  const v1::Envelope* hello() const {
    for (const auto& e : received) {
      if (e.has_hello()) return &e;
    }
    return nullptr;
  }
  std::uint64_t highest_ack() const {
    std::uint64_t ack = 0;
    for (const auto& e : received) ack = std::max<std::uint64_t>(ack, e.ack());
    return ack;
  }

  std::vector<v1::Envelope> received;
  std::size_t undecodable = 0;  // messages that were not envelopes (must stay 0)
  bool eof = false;

 private:
  void poll() {
    if (eof) return;
    socket_.non_blocking(true);
    for (;;) {
      char buf[4096];
      boost::system::error_code ec;
      const std::size_t n = socket_.read_some(asio::buffer(buf), ec);
      if (n > 0) {
        decoder_.feed({reinterpret_cast<const std::uint8_t*>(buf), n},
                      [&](std::span<const std::uint8_t> m) {
                        v1::Envelope e;
                        if (e.ParseFromArray(m.data(), static_cast<int>(m.size()))) {
                          received.push_back(std::move(e));
                        } else {
                          ++undecodable;
                        }
                      });
      }
      if (ec == asio::error::would_block) break;
      if (ec) {  // eof, or a reset after the role closed with our bytes unread: both mean closed
        eof = true;
        break;
      }
    }
    socket_.non_blocking(false);
  }

  tcp::socket socket_;
  backbone::DelimitedDecoder decoder_;
};

std::string delimited(const v1::Envelope& e) {
  std::string out;
  backbone::append_message(out, e);
  return out;
}

v1::Envelope hello(v1::Hello::Role role, std::uint32_t major, std::vector<std::uint32_t> modules,
                   std::uint64_t session_id, const std::string& name = "raw-peer") {
  v1::Envelope e;
  v1::Hello& h = *e.mutable_hello();
  h.set_protocol_major(major);
  h.set_role(role);
  h.set_name(name);
  h.set_session_id(session_id);
  h.set_send_base(1);  // our first reliable payload is seq 1
  for (auto m : modules) h.add_module_ids(m);
  return e;
}

// A serialized v1::Payload holding one batch of `module`.
std::string batch(std::uint32_t module, std::initializer_list<can::Frame> list) {
  v1::Payload p;
  FrameBatchBuilder b;
  b.start(*p.mutable_frames(), module);
  for (const auto& f : list) b.append(*p.mutable_frames(), f);
  return p.SerializeAsString();
}

// An envelope carrying `payload`: reliable with seq >= 1, process data with seq 0.
v1::Envelope data(std::uint64_t seq, const std::string& payload) {
  v1::Envelope e;
  e.set_seq(seq);
  e.set_payload(payload);
  return e;
}

// A surface on a virtual bus with a TcpServer; raw sockets connect to it as gateways.
class SurfaceBadInput : public ::testing::Test {
 protected:
  SurfaceBadInput() {
    surface.start();
    EXPECT_FALSE(server->start("127.0.0.1", 0, [this](auto link) { surface.attach(link); }));
  }
  void TearDown() override {
    server->stop();
    surface.stop();
    observer.close();
    EXPECT_TRUE(run_until(io, [&] { return observer.done(); }));
    EXPECT_TRUE(drains_within(io, 2s));
  }
  RawPeer connect() {
    tcp::socket s(io);
    s.connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), server->port()));
    return RawPeer(std::move(s));
  }
  // A raw gateway that has sent its hello and seen the surface's: data may follow.
  RawPeer ready_gateway(const std::string& name, std::vector<std::uint32_t> modules,
                        std::uint64_t session_id) {
    RawPeer peer = connect();
    peer.send(delimited(hello(v1::Hello::ROLE_GATEWAY, backbone::kProtocolMajor, std::move(modules),
                              session_id, name)));
    // The surface ignores data until its own hello is out, so wait for it.
    EXPECT_TRUE(peer.wait(io, [&] { return peer.hello() != nullptr; }));
    return peer;
  }

  asio::io_context io{1};
  can::VirtualBus medium{io.get_executor(), "surface-bus"};
  BusRecorder observer{io, medium.connect("observer")};
  Surface surface{
      io.get_executor(), "surface", medium.connect("surface"),
      SurfacePolicy{{{"gw-a", {1}, {}}, {"gw-b", {2}, {}}, {"gw-c", {3}, {}}, {"gw-d", {4}, {}}},
                    false},
      patient_tuning()};
  std::shared_ptr<backbone::TcpServer> server = backbone::TcpServer::create(io.get_executor());
};

TEST_F(SurfaceBadInput, RecoverableGarbageIsCountedAndTheLinkStaysUp) {
  RawPeer gw = ready_gateway("gw-a", {1}, 0x1111);
  ASSERT_NE(gw.hello(), nullptr);
  EXPECT_EQ(gw.hello()->hello().role(), v1::Hello::ROLE_SURFACE);
  EXPECT_EQ(gw.hello()->hello().protocol_major(), backbone::kProtocolMajor);
  ASSERT_EQ(surface.gateways_ready(), 1u);

  // Not an envelope: the payload field announces 5 bytes and brings 1.
  std::string not_an_envelope;
  backbone::append_delimited(not_an_envelope, std::vector<std::uint8_t>{0x3A, 0x05, 0x01});
  gw.send(not_an_envelope);
  // A valid envelope whose payload is not a Payload (the frames field is truncated likewise).
  gw.send(delimited(data(1, std::string("\x0A\x05\x01", 3))));
  // A Payload whose batch is inconsistent: an odd number of head bytes.
  v1::Payload odd_head;
  odd_head.mutable_frames()->set_module_id(1);
  odd_head.mutable_frames()->set_head(std::string("\x81\x09\x01", 3));
  gw.send(delimited(data(2, odd_head.SerializeAsString())));
  gw.send(delimited(data(3, batch(9, {can::Frame::standard(0x181, {2})}))));  // never announced
  gw.send(delimited(data(4, batch(1, {can::Frame::standard(0x1A1, {3})}))));

  ASSERT_TRUE(run_until(io, [&] { return !observer.frames.empty(); }));
  ASSERT_EQ(observer.frames.size(), 1u);
  EXPECT_EQ(observer.frames[0], can::Frame::standard(0x1A1, {3}));
  // Every sequenced envelope counts as received (the bad ones are dropped above the session), so
  // the gateway is not asked to resend them forever.
  EXPECT_TRUE(gw.wait(io, [&] { return gw.highest_ack() >= 4; }));

  // Process data (seq 0) bypasses the reliable sequence and is delivered as it comes.
  gw.send(delimited(data(0, batch(1, {can::Frame::standard(0x1A2, {4})}))));
  ASSERT_TRUE(run_until(io, [&] { return observer.frames.size() >= 2; }));
  EXPECT_EQ(observer.frames[1], can::Frame::standard(0x1A2, {4}));

  const SurfaceCounters c = surface.counters();
  EXPECT_EQ(c.session.malformed, 1u);
  EXPECT_EQ(c.malformed_payloads, 2u);
  EXPECT_EQ(c.unknown_module, 1u);
  EXPECT_EQ(c.session.reliable_delivered, 4u);
  EXPECT_EQ(c.session.unreliable_delivered, 1u);
  EXPECT_EQ(c.to_bus, 2u);
  EXPECT_EQ(c.session.protocol_errors, 0u);
  EXPECT_EQ(surface.gateways_ready(), 1u);
  EXPECT_FALSE(gw.eof);
  EXPECT_EQ(gw.undecodable, 0u);
}

TEST_F(SurfaceBadInput, ReliablePayloadsAreDeliveredOnlyInSequence) {
  RawPeer gw = ready_gateway("gw-a", {1}, 0x2222);
  // seq 2 before seq 1: a gap; 2 is kept back (selective repeat) and 1 requested. Then 1 (which
  // releases the buffered 2 behind it), and repeats of 2 and 1: both duplicates, never written.
  gw.send(delimited(data(2, batch(1, {can::Frame::standard(0x1A2, {2})}))));
  ASSERT_TRUE(gw.wait(io, [&] {
    for (const auto& e : gw.received) {
      if (e.resend()) return true;
    }
    return false;
  }));
  gw.send(delimited(data(1, batch(1, {can::Frame::standard(0x1A1, {1})}))));
  gw.send(delimited(data(2, batch(1, {can::Frame::standard(0x1A2, {2})}))));
  gw.send(delimited(data(1, batch(1, {can::Frame::standard(0x1A1, {1})}))));
  ASSERT_TRUE(gw.wait(io, [&] { return gw.highest_ack() >= 2 && observer.frames.size() >= 2; }));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().session.reliable_duplicates == 2; }));
  EXPECT_EQ(observer.frames,
            (std::vector{can::Frame::standard(0x1A1, {1}), can::Frame::standard(0x1A2, {2})}));
  EXPECT_EQ(surface.counters().session.resend_requests, 1u);
}

TEST_F(SurfaceBadInput, UnrecoverableStreamDropsOnlyThatLink) {
  RawPeer bad = ready_gateway("gw-a", {1}, 0xA1);
  RawPeer good = ready_gateway("gw-b", {2}, 0xB1);
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 2; }));

  bad.send(std::string(6, '\xFF'));  // a length prefix longer than any varint32
  EXPECT_TRUE(bad.closed_by_peer(io));
  EXPECT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));

  RawPeer again = ready_gateway("gw-a", {1}, 0xA2);  // the surface still serves (a restart)
  EXPECT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 2; }));
  std::string oversize;  // varint 0x80 0x80 0x80 0x01 = 2 MiB > the 1 MiB limit
  oversize += std::string("\x80\x80\x80\x01", 4);
  again.send(oversize);
  EXPECT_TRUE(again.closed_by_peer(io));
  EXPECT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1; }));

  // The other gateway's link never noticed.
  good.send(delimited(data(1, batch(2, {can::Frame::standard(0x1C5, {5})}))));
  ASSERT_TRUE(run_until(io, [&] { return !observer.frames.empty(); }));
  EXPECT_EQ(observer.frames.front(), can::Frame::standard(0x1C5, {5}));
  EXPECT_FALSE(good.eof);
  EXPECT_EQ(surface.counters().session.links, 3u);
  EXPECT_EQ(surface.counters().session.peer_restarts, 1u);
}

TEST_F(SurfaceBadInput, DataBeforeHelloIsAProtocolErrorAndTheLinkIsClosed) {
  RawPeer early = connect();
  early.send(delimited(data(1, batch(1, {can::Frame::standard(0x181, {1})}))));
  EXPECT_TRUE(early.closed_by_peer(io));
  EXPECT_TRUE(early.received.empty());  // not even a hello: the surface had no stream for it
  EXPECT_EQ(surface.counters().session.protocol_errors, 1u);
  EXPECT_EQ(surface.counters().session.refusals_sent, 0u);
  EXPECT_TRUE(observer.frames.empty());
  EXPECT_EQ(surface.gateways_ready(), 0u);
}

// What a refused raw peer read: exactly one envelope, a Refusal, then EOF.
const v1::Refusal* only_refusal(const RawPeer& peer) {
  if (peer.received.size() != 1 || !peer.received[0].has_refusal()) return nullptr;
  return &peer.received[0].refusal();
}

// Over plain TCP the peer proved nothing: version and role refusals name no reason either.
TEST_F(SurfaceBadInput, WrongVersionAndWrongRoleAreRefusedTellingOnlyThat) {
  RawPeer future = connect();
  future.send(delimited(hello(v1::Hello::ROLE_GATEWAY, backbone::kProtocolMajor + 1, {1}, 0xF1)));
  ASSERT_TRUE(future.closed_by_peer(io));
  const v1::Refusal* version = only_refusal(future);
  ASSERT_NE(version, nullptr);
  EXPECT_EQ(version->reason(), v1::Refusal::REASON_UNSPECIFIED);
  EXPECT_EQ(version->detail(), "refused");

  RawPeer twin = connect();
  twin.send(delimited(hello(v1::Hello::ROLE_SURFACE, backbone::kProtocolMajor, {}, 0xF2)));
  ASSERT_TRUE(twin.closed_by_peer(io));
  const v1::Refusal* role = only_refusal(twin);
  ASSERT_NE(role, nullptr);
  EXPECT_EQ(role->reason(), v1::Refusal::REASON_UNSPECIFIED);
  EXPECT_EQ(role->detail(), "refused");

  const SurfaceCounters c = surface.counters();
  EXPECT_EQ(c.session.refusals_sent, 2u);
  EXPECT_EQ(c.session.links, 0u);
  EXPECT_EQ(surface.gateways_ready(), 0u);
}

// Over plain TCP the peer proved nothing: it learns only that it was refused, no names, modules
// or ids (the surface's log has them).
TEST_F(SurfaceBadInput, AModuleNotItsOwnOrAnnouncedTwiceIsRefusedAndThePeerToldOnlyRefused) {
  RawPeer owner = ready_gateway("gw-a", {1}, 0xA1);
  RawPeer rival = connect();
  rival.send(
      delimited(hello(v1::Hello::ROLE_GATEWAY, backbone::kProtocolMajor, {3, 1}, 0xC1, "gw-c")));
  ASSERT_TRUE(rival.closed_by_peer(io));
  const v1::Refusal* duplicate = only_refusal(rival);
  ASSERT_NE(duplicate, nullptr);
  EXPECT_EQ(duplicate->reason(), v1::Refusal::REASON_UNSPECIFIED);
  EXPECT_EQ(duplicate->detail(), "refused");

  RawPeer stutter = connect();  // one hello naming the same module twice
  stutter.send(
      delimited(hello(v1::Hello::ROLE_GATEWAY, backbone::kProtocolMajor, {4, 4}, 0xD1, "gw-d")));
  ASSERT_TRUE(stutter.closed_by_peer(io));
  ASSERT_NE(only_refusal(stutter), nullptr);
  EXPECT_EQ(only_refusal(stutter)->detail(), "refused");

  EXPECT_EQ(surface.counters().session.refusals_sent, 2u);
  EXPECT_EQ(surface.gateways_ready(), 1u);
  EXPECT_FALSE(owner.eof);
}

TEST(GatewayBadInput, GarbageFromTheSurfaceDropsTheLinkAndTheGatewayReconnects) {
  asio::io_context io{1};
  can::VirtualBus bus(io.get_executor(), "module-bus");
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());
  std::vector<GatewayModule> modules;
  modules.push_back({1, bus.connect("gateway"), true});
  BusRecorder node(io, bus.connect("node"));
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules), patient_tuning());
  gateway.start();

  tcp::acceptor acceptor(io, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  backbone::ClientOptions options;
  options.backoff_min = 10ms;
  auto client = backbone::TcpClient::create(io.get_executor(), "127.0.0.1",
                                            acceptor.local_endpoint().port(), options);
  client->start([&](auto link) { gateway.attach(link); });

  // The client connects from the loop: accept without blocking it.
  acceptor.non_blocking(true);
  auto accept = [&]() -> std::optional<RawPeer> {
    tcp::socket socket(io);
    const bool ok = run_until(io, [&] {
      boost::system::error_code ec;
      acceptor.accept(socket, ec);
      return !ec;
    });
    if (!ok) return std::nullopt;
    socket.non_blocking(false);
    return RawPeer(std::move(socket));
  };
  constexpr std::uint64_t kSurfaceSession = 0x5005;

  std::optional<RawPeer> first = accept();
  ASSERT_TRUE(first);
  // The gateway's stream is preset, so its hello goes out without waiting for ours.
  ASSERT_TRUE(first->wait(io, [&] { return first->hello() != nullptr; }));
  const v1::Hello& announced = first->hello()->hello();
  EXPECT_EQ(announced.role(), v1::Hello::ROLE_GATEWAY);
  EXPECT_EQ(announced.protocol_major(), backbone::kProtocolMajor);
  EXPECT_EQ(announced.name(), "gw");
  ASSERT_EQ(announced.module_ids_size(), 1);
  EXPECT_EQ(announced.module_ids(0), 1u);
  EXPECT_EQ(announced.resume_session_id(), 0u);  // it has never heard of a surface

  first->send(delimited(hello(v1::Hello::ROLE_SURFACE, backbone::kProtocolMajor, {},
                              kSurfaceSession, "raw-surface")));
  ASSERT_TRUE(run_until(io, [&] { return gateway.connected(); }));
  // A surface frame for surface node 40 = module 1 node 8 reaches the module bus as 0x608.
  first->send(delimited(data(1, batch(kAnyModule, {can::Frame::standard(0x628, {7})}))));
  first->send(delimited(data(2, "\x0A\x05\x01")));                                // not a Payload
  first->send(delimited(data(3, batch(7, {can::Frame::standard(0x628, {8})}))));  // not served
  ASSERT_TRUE(run_until(io, [&] { return !node.frames.empty(); }));
  EXPECT_EQ(node.frames.at(0), can::Frame::standard(0x608, {7}));
  ASSERT_TRUE(first->wait(io, [&] { return first->highest_ack() >= 3; }));
  GatewayCounters c = gateway.counters();
  EXPECT_EQ(c.malformed_payloads, 1u);
  EXPECT_EQ(c.unknown_module, 1u);
  EXPECT_TRUE(gateway.connected());

  first->send(std::string(6, '\xFF'));  // an unrecoverable stream
  ASSERT_TRUE(run_until(io, [&] { return !gateway.connected(); }));
  EXPECT_TRUE(first->closed_by_peer(io));

  std::optional<RawPeer> second = accept();
  ASSERT_TRUE(second);
  EXPECT_EQ(client->counters().connects, 2u);
  // The new link resumes the stream: the gateway's hello says what it already received from us.
  ASSERT_TRUE(second->wait(io, [&] { return second->hello() != nullptr; }));
  EXPECT_EQ(second->hello()->hello().resume_session_id(), kSurfaceSession);
  EXPECT_EQ(second->hello()->ack(), 3u);
  second->send(delimited(hello(v1::Hello::ROLE_SURFACE, backbone::kProtocolMajor, {},
                               kSurfaceSession, "raw-surface")));
  ASSERT_TRUE(run_until(io, [&] { return gateway.connected(); }));
  // A repeat of seq 1 is a duplicate (not written twice); seq 4 is new.
  second->send(delimited(data(1, batch(kAnyModule, {can::Frame::standard(0x628, {7})}))));
  second->send(delimited(data(4, batch(kAnyModule, {can::Frame::standard(0x629, {9})}))));
  ASSERT_TRUE(run_until(io, [&] { return node.frames.size() >= 2; }));
  ASSERT_TRUE(second->wait(io, [&] { return second->highest_ack() >= 4; }));
  EXPECT_EQ(node.frames,
            (std::vector{can::Frame::standard(0x608, {7}), can::Frame::standard(0x609, {9})}));
  c = gateway.counters();
  EXPECT_EQ(c.session.reliable_duplicates, 1u);
  EXPECT_EQ(c.session.links, 2u);
  EXPECT_EQ(c.to_buses, 2u);

  client->stop();
  gateway.stop();
  node.close();
  EXPECT_TRUE(run_until(io, [&] { return node.done(); }));
  acceptor.close();
  EXPECT_TRUE(drains_within(io, 2s));
}

// Protocol 2.6 sends FrameBatch.head_runs only to a peer that says it decodes them: a raw surface
// at minor 5 gets the plain form of the same backlog a surface at minor 6 gets in runs, and the
// gateway decodes both forms from the surface.
void gateway_talks_to_a_surface_at_minor(std::uint32_t minor) {
  SCOPED_TRACE("surface at protocol minor " + std::to_string(minor));
  asio::io_context io{1};
  can::VirtualBus bus(io.get_executor(), "module-bus");
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());
  std::vector<GatewayModule> modules;
  modules.push_back({1, bus.connect("gateway"), true});
  BusRecorder node(io, bus.connect("node"));
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules), patient_tuning());
  gateway.start();
  tcp::acceptor acceptor(io, tcp::endpoint(asio::ip::make_address("127.0.0.1"), 0));
  auto client =
      backbone::TcpClient::create(io.get_executor(), "127.0.0.1", acceptor.local_endpoint().port());
  client->start([&](auto link) { gateway.attach(link); });
  acceptor.non_blocking(true);
  tcp::socket socket(io);
  ASSERT_TRUE(run_until(io, [&] {
    boost::system::error_code ec;
    acceptor.accept(socket, ec);
    return !ec;
  }));
  socket.non_blocking(false);
  RawPeer surface(std::move(socket));
  ASSERT_TRUE(surface.wait(io, [&] { return surface.hello() != nullptr; }));
  EXPECT_EQ(surface.hello()->hello().protocol_minor(), backbone::kProtocolMinor);

  // A backlog of one EMCY COB-ID (reliable, never conflated) while the surface is not there yet.
  constexpr std::size_t kFrames = 6;
  for (std::uint8_t i = 0; i < kFrames; ++i)
    ASSERT_TRUE(node.send(can::Frame::standard(0x081, {i})));
  ASSERT_TRUE(run_until(io, [&] { return gateway.counters().from_buses >= kFrames; }));
  v1::Envelope h = hello(v1::Hello::ROLE_SURFACE, backbone::kProtocolMajor, {}, 0x600 + minor);
  h.mutable_hello()->set_protocol_minor(minor);
  surface.send(delimited(h));

  std::size_t frames = 0;
  std::size_t head_words = 0;
  int runs = 0;
  std::vector<can::Frame> decoded;
  ASSERT_TRUE(surface.wait(io, [&] {
    frames = head_words = 0;
    runs = 0;
    decoded.clear();
    for (const auto& e : surface.received) {
      v1::Payload p;
      if (e.payload().empty() || !p.ParseFromString(e.payload()) || !p.has_frames()) continue;
      EXPECT_EQ(decode_frame_batch(p.frames(), decoded), BatchError::none);
      head_words += p.frames().head().size() / 2;
      runs += p.frames().head_runs_size();
    }
    return decoded.size() >= kFrames;
  }));
  ASSERT_EQ(decoded.size(), kFrames);
  for (std::uint8_t i = 0; i < kFrames; ++i) EXPECT_EQ(decoded[i].data[0], i);
  if (minor >= kHeadRunsMinor) {
    EXPECT_GT(runs, 0);
    EXPECT_LT(head_words, kFrames);
  } else {
    EXPECT_EQ(runs, 0);
    EXPECT_EQ(head_words, kFrames);
  }

  // From the surface: a batch in the form its minor allows, written to the module bus in order.
  v1::Payload p;
  FrameBatchBuilder b(false, minor >= kHeadRunsMinor);
  b.start(*p.mutable_frames(), kAnyModule);
  for (std::uint8_t i = 0; i < 3; ++i)
    b.append(*p.mutable_frames(), can::Frame::standard(0x628, {i}));
  EXPECT_EQ(p.frames().head_runs_size(), minor >= kHeadRunsMinor ? 2 : 0);
  surface.send(delimited(data(1, p.SerializeAsString())));
  ASSERT_TRUE(run_until(io, [&] { return node.frames.size() >= 3; }));
  EXPECT_EQ(node.frames,
            (std::vector{can::Frame::standard(0x608, {0}), can::Frame::standard(0x608, {1}),
                         can::Frame::standard(0x608, {2})}));
  EXPECT_EQ(gateway.counters().malformed_payloads, 0u);

  client->stop();
  gateway.stop();
  node.close();
  EXPECT_TRUE(run_until(io, [&] { return node.done(); }));
  acceptor.close();
  EXPECT_TRUE(drains_within(io, 2s));
}

TEST(GatewayHeadRuns, ASurfaceAtProtocol2_5GetsThePlainFormAndIsStillDecoded) {
  gateway_talks_to_a_surface_at_minor(5);
}

TEST(GatewayHeadRuns, ASurfaceAtProtocol2_6GetsHeadRunsAndSendsThem) {
  gateway_talks_to_a_surface_at_minor(kHeadRunsMinor);
}

}  // namespace
}  // namespace canbridge::bridge
