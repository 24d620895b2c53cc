// PDO Packets through a real gateway and surface in process (issue 6): TPDOP fragments of a pdop
// module cross the backbone as whole packets and reappear on the surface bus under the node's
// surface id; broken packets are reported, not delivered; a bus overrun discards what it may have
// broken; an RPDOP packet from a master on the surface bus reaches the node paced by the node's own
// acknowledgements, and the master's final acknowledgement follows the node's.
#include <gtest/gtest.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/gateway.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "canopen/pdop.hpp"
#include "routing/node_map.hpp"
#include "routing/pdop_segmenter.hpp"
#include "sim/rpdop_receiver.hpp"
#include "tests/bridge/loopback_roles.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
namespace pdop = canopen::pdop;
using namespace std::chrono_literals;

using test::BusRecorder;
using test::run_until;

constexpr ModuleId kModule = 1;
// Local node 1 -> surface 3, local 2 -> surface 4 (pdop nodes need surface ids 1..31).
constexpr canopen::NodeId kLocalA = 1, kSurfaceA = 3, kLocalB = 2, kSurfaceB = 4;

std::vector<std::uint8_t> pattern(std::size_t size, std::uint8_t seed) {
  std::vector<std::uint8_t> bytes(size);
  for (std::size_t i = 0; i < size; ++i) bytes[i] = static_cast<std::uint8_t>(seed + 7 * i);
  return bytes;
}

// The surface's bus with a transmit queue the test controls: `room` frames more, then refusals.
class RoomLimitedBus final : public can::Bus {
 public:
  static constexpr std::size_t kUnbounded = std::numeric_limits<std::size_t>::max();
  RoomLimitedBus(asio::any_io_executor executor, std::unique_ptr<can::Bus> inner)
      : inner_(std::move(inner)), room_changed_(executor, asio::steady_timer::time_point::max()) {}
  std::size_t room = kUnbounded;
  void set_room(std::size_t frames) {
    room = frames;
    room_changed_.cancel();
  }
  asio::awaitable<std::error_code> wait_send_room(std::size_t frames) override {
    while (!closed_ && send_room() < frames) {
      co_await room_changed_.async_wait(asio::as_tuple(asio::use_awaitable));
    }
    if (closed_) co_return std::make_error_code(std::errc::operation_canceled);
    co_return std::error_code{};
  }

  const std::string& name() const override { return inner_->name(); }
  asio::awaitable<std::error_code> receive_batch(std::vector<can::Frame>& out) override {
    return inner_->receive_batch(out);
  }
  using can::Bus::send;  // the batch send: frame by frame through this one
  bool send(const can::Frame& frame) override {
    if (room == 0) return false;
    if (room != kUnbounded) --room;
    return inner_->send(frame);
  }
  std::size_t send_room() const override { return std::min(room, inner_->send_room()); }
  can::BusCounters counters() const override { return inner_->counters(); }
  void on_state_change(std::function<void(can::BusState)> handler) override {
    inner_->on_state_change(std::move(handler));
  }
  void close() override {
    closed_ = true;
    room_changed_.cancel();
    inner_->close();
  }

 private:
  std::unique_ptr<can::Bus> inner_;
  asio::steady_timer room_changed_;  // condition variable: set_room(), close()
  bool closed_ = false;
};

struct SeenPacket {
  canopen::NodeId surface_node = 0;
  canopen::NodeId local_node = 0;
  unsigned tpdo = 0;
  std::vector<std::uint8_t> data;
};

class PdopBridging : public ::testing::Test {
 protected:
  // `module_rx_capacity` bounds the gateway's receive queue on the module bus (overrun test).
  void start(bool reassemble = true, std::size_t module_rx_capacity = 4096) {
    module_bus_ =
        std::make_unique<can::VirtualBus>(io.get_executor(), "pdop-module", module_rx_capacity);
    NodeMap map;
    ASSERT_TRUE(
        map.add_module(kModule, {{kLocalA, kSurfaceA}, {kLocalB, kSurfaceB}}, IdProfile::pdop)
            .empty());
    std::vector<GatewayModule> modules;
    GatewayModule m;
    m.id = kModule;
    m.bus = module_bus_->connect("gateway");
    m.conflate_pdos = false;
    m.reassemble_pdop = reassemble;
    modules.push_back(std::move(m));
    node = std::make_unique<BusRecorder>(io, module_bus_->connect("node"));
    gateway =
        std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules));
    surface.on_pdop_packet([this](const SurfacePdopPacket& p) {
      packets.push_back({p.surface_node, p.local_node, p.tpdo, {p.data.begin(), p.data.end()}});
    });
    ASSERT_TRUE(start_linked_over_loopback(io, surface, *gateway, server, client));
  }

  void TearDown() override {
    if (client) client->stop();
    if (gateway) gateway->stop();
    server->stop();
    surface.stop();
    master.close();
    if (node) node->close();
    EXPECT_TRUE(run_until(io, [&] { return master.done() && (!node || node->done()); }));
  }

  void send_packet(canopen::NodeId local, unsigned tpdo, const std::vector<std::uint8_t>& data) {
    for (const can::Frame& f : pdop::fragment(pdop::tpdo_base(tpdo), local, data)) {
      ASSERT_TRUE(node->send(f));
    }
  }

  // The master's frames on TPDO COB-IDs of surface node `surface`, in order.
  std::vector<can::Frame> tpdo_frames_on_surface(canopen::NodeId surface_node) const {
    std::vector<can::Frame> out;
    for (const can::Frame& f : master.frames) {
      const auto id = pdop::decode(f.id);
      if (id.node == surface_node && pdop::tpdo_number(id.function_code) && f.id >= 0x180 &&
          f.id < 0x500) {
        out.push_back(f);
      }
    }
    return out;
  }

  asio::io_context io{1};
  std::unique_ptr<can::VirtualBus> module_bus_;
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  RoomLimitedBus* surface_port = nullptr;
  Surface surface{io.get_executor(), "surface",
                  [this] {
                    auto bus = std::make_unique<RoomLimitedBus>(io.get_executor(),
                                                                surface_bus.connect("surface"));
                    surface_port = bus.get();
                    return bus;
                  }(),
                  SurfacePolicy{{{"gw", {kModule}, {kSurfaceA, kSurfaceB}}}, false}};
  std::shared_ptr<backbone::TcpServer> server = backbone::TcpServer::create(io.get_executor());
  std::unique_ptr<BusRecorder> node;
  std::unique_ptr<Gateway> gateway;
  std::shared_ptr<backbone::TcpClient> client;
  std::vector<SeenPacket> packets;
};

TEST_F(PdopBridging, TpdopPacketsCrossWholeAndReappearUnderTheSurfaceId) {
  start();
  const auto a = pattern(100, 1);  // 13 fragments
  const auto b = pattern(20, 2);   // 3 fragments
  const auto c = pattern(5, 3);    // a one-frame packet: a plain TPDO
  // Interleaved on the bus: node A's TPDO1 and node B's TPDO2, fragment by fragment.
  const auto fa = pdop::fragment(pdop::tpdo_base(1), kLocalA, a);
  const auto fb = pdop::fragment(pdop::tpdo_base(2), kLocalB, b);
  for (std::size_t i = 0; i < fa.size(); ++i) {
    ASSERT_TRUE(node->send(fa[i]));
    if (i < fb.size()) {
      ASSERT_TRUE(node->send(fb[i]));
    }
  }
  send_packet(kLocalA, 3, c);
  ASSERT_TRUE(run_until(io, [&] { return packets.size() == 3; }));

  EXPECT_EQ(packets[0].surface_node, kSurfaceB);  // B's packet ended first
  EXPECT_EQ(packets[0].local_node, kLocalB);
  EXPECT_EQ(packets[0].tpdo, 2u);
  EXPECT_EQ(packets[0].data, b);
  EXPECT_EQ(packets[1].surface_node, kSurfaceA);
  EXPECT_EQ(packets[1].tpdo, 1u);
  EXPECT_EQ(packets[1].data, a);
  EXPECT_EQ(packets[2].tpdo, 3u);
  EXPECT_EQ(packets[2].data, c);

  // On the surface bus: exactly the fragments node A would send as surface node 3.
  ASSERT_TRUE(run_until(io, [&] { return tpdo_frames_on_surface(kSurfaceA).size() == 14; }));
  auto expected = pdop::fragment(pdop::tpdo_base(1), kSurfaceA, a);
  const auto expected_c = pdop::fragment(pdop::tpdo_base(3), kSurfaceA, c);
  expected.insert(expected.end(), expected_c.begin(), expected_c.end());
  const auto got = tpdo_frames_on_surface(kSurfaceA);
  ASSERT_EQ(got.size(), expected.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].id, expected[i].id) << i;
    EXPECT_EQ(got[i].len, expected[i].len) << i;
    EXPECT_EQ(got[i].data, expected[i].data) << i;
  }
  EXPECT_EQ(tpdo_frames_on_surface(kSurfaceB).size(), 3u);

  const GatewayCounters g = gateway->counters();
  EXPECT_EQ(g.pdop.packets, 3u);
  EXPECT_EQ(g.pdop.fragments, 17u);
  EXPECT_EQ(g.pdop.packet_bytes, 125u);
  EXPECT_EQ(g.outbox.frames_sent, 0u);  // no fragment crossed as a frame of its own
  EXPECT_EQ(surface.counters().pdop.packets, 3u);
  EXPECT_NE(gateway->stats_line().find("pdop packets 3 (125 bytes, 17 fragments) discarded 0"),
            std::string::npos)
      << gateway->stats_line();
}

TEST_F(PdopBridging, PacketsWaitWholeAndInOrderWhileTheSurfaceBusIsFull) {
  start();
  surface_port->set_room(10);  // less than one packet's 13 fragments
  const auto a = pattern(100, 1), b = pattern(100, 2);
  send_packet(kLocalA, 1, a);
  send_packet(kLocalA, 1, b);
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().pdop.packets == 2; }));
  EXPECT_TRUE(tpdo_frames_on_surface(kSurfaceA).empty());  // no partial packet on the bus
  surface_port->set_room(RoomLimitedBus::kUnbounded);      // the queue drains
  ASSERT_TRUE(run_until(io, [&] { return tpdo_frames_on_surface(kSurfaceA).size() == 26; }));
  auto expected = pdop::fragment(pdop::tpdo_base(1), kSurfaceA, a);
  const auto then = pdop::fragment(pdop::tpdo_base(1), kSurfaceA, b);
  expected.insert(expected.end(), then.begin(), then.end());
  const auto got = tpdo_frames_on_surface(kSurfaceA);
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].id, expected[i].id) << i;
    EXPECT_EQ(got[i].data, expected[i].data) << i;
  }
  EXPECT_EQ(surface.counters().pdop_bus_refused, 0u);
  EXPECT_EQ(surface.counters().bus_refused, 0u);
}

TEST_F(PdopBridging, ABrokenPacketIsReportedToTheSurfaceAndNeverDelivered) {
  start();
  const auto frames = pdop::fragment(pdop::tpdo_base(1), kLocalA, pattern(40, 9));  // 5
  ASSERT_TRUE(node->send(frames[0]));
  ASSERT_TRUE(node->send(frames[2]));  // fragment 1 lost: the toggle is wrong
  ASSERT_TRUE(node->send(frames[3]));
  ASSERT_TRUE(node->send(frames[4]));  // c = 0: the stream is in step again
  send_packet(kLocalA, 1, pattern(16, 4));
  ASSERT_TRUE(run_until(io, [&] { return packets.size() == 1; }));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().pdop.discards == 1; }));
  EXPECT_EQ(packets[0].data, pattern(16, 4));
  EXPECT_EQ(gateway->counters().pdop.discards, 1u);
  EXPECT_EQ(tpdo_frames_on_surface(kSurfaceA).size(), 2u);  // only the good packet
}

TEST_F(PdopBridging, ALastFragmentReceivedTwiceIsDeliveredFlaggedAsAProbableRepeat) {
  start();
  const auto frames = pdop::fragment(pdop::tpdo_base(1), kLocalA, pattern(17, 3));  // t = 0 last
  for (const can::Frame& f : frames) ASSERT_TRUE(node->send(f));
  ASSERT_TRUE(node->send(frames.back()));  // CAN's double reception of the last fragment
  ASSERT_TRUE(run_until(io, [&] { return packets.size() == 2; }));
  EXPECT_EQ(packets[1].data.size(), 1u);
  EXPECT_EQ(surface.counters().pdop.probable_repeats, 1u);
  EXPECT_NE(surface.stats_line().find("probable-repeats 1"), std::string::npos);
}

TEST_F(PdopBridging, LostFramesOnTheModuleBusDiscardWhatTheyMayHaveBroken) {
  // The gateway's receive queue holds 8 frames: a 40-fragment packet sent at once overflows it.
  start(true, 8);
  send_packet(kLocalA, 1, pattern(320, 5));  // 8 fragments taken, 32 lost
  ASSERT_TRUE(run_until(io, [&] { return gateway->counters().from_buses >= 8; }));
  // The next packet's first frame follows the loss. Without the loss mark it would continue the
  // open packet (its toggle matches) and a 320-byte merge would be delivered.
  send_packet(kLocalA, 1, pattern(64, 6));
  ASSERT_TRUE(run_until(io, [&] { return gateway->counters().from_buses >= 16; }));
  send_packet(kLocalA, 1, pattern(24, 7));
  ASSERT_TRUE(run_until(io, [&] { return packets.size() == 1; }));
  EXPECT_EQ(packets[0].data, pattern(24, 7));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().pdop.discards == 1; }));
  EXPECT_EQ(gateway->counters().pdop.discards, 1u);
}

TEST_F(PdopBridging, FragmentsOfANodeWithoutASurfaceIdAreCountedNotReassembled) {
  start();
  send_packet(9, 1, pattern(20, 1));  // local node 9 has no surface id: 3 fragments
  send_packet(kLocalA, 1, pattern(20, 2));
  ASSERT_TRUE(run_until(io, [&] { return packets.size() == 1; }));
  EXPECT_EQ(packets[0].local_node, kLocalA);
  std::uint64_t dropped = 0;
  for (auto d : gateway->counters().translation) dropped += d;
  EXPECT_EQ(dropped, 3u);
  EXPECT_EQ(gateway->counters().pdop.packets, 1u);
}

TEST_F(PdopBridging, WithoutReassemblyFragmentsCrossOneByOne) {
  start(false);
  const auto data = pattern(30, 8);  // 4 fragments
  send_packet(kLocalA, 1, data);
  ASSERT_TRUE(run_until(io, [&] { return tpdo_frames_on_surface(kSurfaceA).size() == 4; }));
  EXPECT_TRUE(packets.empty());
  EXPECT_EQ(gateway->counters().pdop.packets, 0u);
  EXPECT_EQ(gateway->counters().outbox.frames_sent, 4u);
}

// The node on the module bus: the simulated fpga node's RPDOP receiver, answering the gateway.
// Checks, for every fragment it receives, that the sender stayed within the node's last credit.
class NodeReceiver {
 public:
  NodeReceiver(BusRecorder& bus, canopen::NodeId local, std::uint8_t window)
      : bus_(bus), receiver_(local, spec(window)), limit_(window) {
    bus_.on_frames = [this] { on_frames(); };
  }
  std::vector<sim::RpdopReceiver::Packet> completed;
  std::uint32_t fragments = 0;
  std::uint32_t over_limit = 0;  // fragments sent beyond received + credit
  std::uint32_t acks = 0;

 private:
  static sim::PdopSpec spec(std::uint8_t window) {
    sim::PdopSpec s;
    s.window = window;
    return s;
  }
  void on_frames() {
    for (; seen_ < bus_.frames.size(); ++seen_) {
      const can::Frame& f = bus_.frames[seen_];
      std::vector<can::Frame> out;
      const bool fragment =
          !f.is_remote() && f.len > 0 && pdop::rpdo_number(pdop::decode(f.id).function_code);
      if (fragment) {
        ++fragments;
        if (next_ >= limit_) ++over_limit;
        ++next_;
      }
      receiver_.on_frame(f, std::chrono::steady_clock::now(), out, completed);
      for (const can::Frame& ack : out) {
        if (const auto a = pdop::decode_ack(ack)) {
          ++acks;
          limit_ = a->received + a->credit;
          next_ = a->received;
          if (a->status == pdop::AckStatus::complete) {
            next_ = 0;
            limit_ = a->credit;
          }
        }
        ASSERT_TRUE(bus_.send(ack));
      }
    }
  }
  BusRecorder& bus_;
  sim::RpdopReceiver receiver_;
  std::size_t seen_ = 0;
  std::uint32_t next_ = 0;   // index of the next fragment the node expects
  std::uint32_t limit_ = 0;  // fragments below this index may be outstanding
};

TEST_F(PdopBridging, RpdopFromTheSurfaceMasterReachesTheNodePacedByItsAcknowledgements) {
  start();
  constexpr std::uint8_t kWindow = 4;
  NodeReceiver receiver(*node, kLocalA, kWindow);
  // The surface learns its pdop nodes from the gateway's first payload.
  ASSERT_TRUE(run_until(io, [&] { return surface.rpdop_relay().relayed(kSurfaceA); }));

  // The master: the RPDOP sender core, on the surface bus.
  PdopSegmenterOptions options;
  options.window = kWindow;
  PdopSegmenter sender(options);
  PdopSegmenter::Output out;
  std::size_t master_seen = 0;
  auto pump = [&] {
    for (const can::Frame& f : out.frames) ASSERT_TRUE(master.send(f));
    out.frames.clear();
  };
  master.on_frames = [&] {
    for (; master_seen < master.frames.size(); ++master_seen) {
      sender.on_frame(master.frames[master_seen], std::chrono::steady_clock::now(), out);
    }
    pump();
  };
  const auto data = pattern(1024, 11);  // 128 fragments
  sender.submit(kSurfaceA, 1, data, 77, std::chrono::steady_clock::now(), out);
  pump();
  ASSERT_TRUE(run_until(io, [&] {
    sender.tick(std::chrono::steady_clock::now(), out);
    pump();
    return !out.outcomes.empty();
  }));
  ASSERT_EQ(out.outcomes.size(), 1u);
  EXPECT_EQ(out.outcomes[0].result, PdopResult::complete) << to_string(out.outcomes[0]);
  ASSERT_EQ(receiver.completed.size(), 1u);
  EXPECT_EQ(receiver.completed[0].bytes, data);
  EXPECT_EQ(receiver.fragments, 128u);
  EXPECT_EQ(receiver.over_limit, 0u);
  EXPECT_GE(receiver.acks, 128u / kWindow);  // paced by the node, window by window
  EXPECT_EQ(gateway->counters().pdop.rpdop_complete, 1u);
  EXPECT_EQ(surface.counters().pdop.rpdop_complete, 1u);
}

TEST_F(PdopBridging, RpdopToANodeWhoseGatewayIsNotConnectedEndsAtOnceWith0x82) {
  start();
  ASSERT_TRUE(run_until(io, [&] { return surface.rpdop_relay().relayed(kSurfaceA); }));
  client->stop();
  gateway->stop();
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 0; }));
  PdopSegmenter sender;
  PdopSegmenter::Output out;
  std::size_t seen = 0;
  master.on_frames = [&] {
    for (; seen < master.frames.size(); ++seen) {
      sender.on_frame(master.frames[seen], std::chrono::steady_clock::now(), out);
    }
  };
  const auto started = std::chrono::steady_clock::now();
  sender.submit(kSurfaceA, 2, pattern(20, 5), 1, started, out);
  ASSERT_TRUE(run_until(io, [&] {
    for (const can::Frame& f : out.frames) EXPECT_TRUE(master.send(f));
    out.frames.clear();
    return !out.outcomes.empty();
  }));
  EXPECT_EQ(out.outcomes[0].result, PdopResult::receiver_abort);
  EXPECT_EQ(out.outcomes[0].status, pdop::AckStatus::out_of_memory);
  EXPECT_LT(std::chrono::steady_clock::now() - started, 100ms);  // not the sender's timeout
  EXPECT_EQ(surface.counters().pdop.rpdop_failed, 1u);
}

}  // namespace
}  // namespace canbridge::bridge
