// The gateway's reliable drop counters count frames, each once, and only frames that were
// dropped (issue 27: "reliable-too-old" showed 1,750 in a run where all 20,000 frames arrived): a
// real Gateway on a virtual module bus, the surface played by a script that receives every frame
// and never acknowledges one.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/backbone/envelopes.hpp"
#include "tests/backbone/scripted_peer.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using backbone::testing::hello;
using backbone::testing::hello_from;
using backbone::testing::PeerIdentity;
using backbone::testing::PeerScript;
using backbone::testing::ScriptedPeer;
using can::Frame;

constexpr ModuleId kModule = 1;
constexpr canopen::NodeId kLocal = 2, kSurface = 5;

// An EMCY (reliable) of the node carrying a sequence number.
Frame emcy(std::uint32_t seq) {
  return Frame::standard(0x080u + kLocal, {0x00, 0x10, 0x01, static_cast<std::uint8_t>(seq),
                                           static_cast<std::uint8_t>(seq >> 8)});
}

std::uint64_t drop_count(const RoleStatistics& s, const std::string& name) {
  for (const auto& d : s.drops) {
    if (d.reason == name) return d.count;
  }
  ADD_FAILURE() << "no drop counter " << name;
  return 0;
}

TEST(GatewayDropCounts, FramesThatArrivedButWereNeverAcknowledgedAreNoDrops) {
  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module"};
  test::BusRecorder node{io, module_bus.connect("node")};
  NodeMap map;
  ASSERT_TRUE(map.add_module(kModule, {{kLocal, kSurface}}).empty());
  std::vector<GatewayModule> modules(1);
  modules[0].id = kModule;
  modules[0].bus = module_bus.connect("gateway");
  BackboneTuning tuning;
  tuning.session.keepalive_interval = 20ms;
  tuning.session.dead_after = 10s;         // the silent script is no dead link
  tuning.session.retransmit_timeout = 5s;  // nothing is resent: what arrived arrived once
  tuning.session.reliable_max_age = 100ms;
  tuning.outbox.reliable_max_age = 100ms;
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules), tuning);
  gateway.start();

  constexpr std::uint32_t kFrames = 10;
  ScriptedPeer* surface = nullptr;
  // The frames in every payload the script received (none is acknowledged).
  const auto frames_arrived = [&] {
    std::uint64_t n = 0;
    v1::Payload parsed;
    std::vector<Frame> decoded;
    for (const auto& r : surface->received()) {
      const v1::Envelope& e = r.envelope;
      if (e.seq() == 0 || !e.has_payload() || e.payload().empty()) continue;
      const std::span<const std::uint8_t> bytes(
          reinterpret_cast<const std::uint8_t*>(e.payload().data()), e.payload().size());
      if (!decode_frame_payload(bytes, parsed, decoded)) n += decoded.size();
    }
    return n;
  };
  PeerIdentity surface_identity;
  surface_identity.name = "surface";
  PeerScript script;
  script.expect(hello_from(v1::Hello::ROLE_GATEWAY))
      .reply(hello(surface_identity))
      .wait_for("the gateway is linked", [&] { return gateway.connected(); })
      .act("the node sends its EMCYs",
           [&] {
             for (std::uint32_t i = 0; i < kFrames; ++i) node.send(emcy(i));
           })
      .wait_for("every frame arrived, then grew too old unacknowledged", [&] {
        return frames_arrived() == kFrames &&
               gateway.counters().session_frames_expired_unacked == kFrames;
      });
  auto pair = backbone::make_memory_link_pair(io.get_executor());
  ScriptedPeer peer(pair.b, std::move(script));
  surface = &peer;
  gateway.attach(pair.a);
  ASSERT_TRUE(peer.finishes(io)) << "frames arrived " << frames_arrived() << "; "
                                 << gateway.stats_line();

  const GatewayCounters c = gateway.counters();
  EXPECT_EQ(c.outbox.frames_sent, kFrames);
  EXPECT_EQ(c.outbox.reliable_too_old, 0u);
  EXPECT_EQ(c.session_frames_too_old, 0u);
  // Every frame arrived: none of them is a drop, though every payload became a tombstone.
  EXPECT_GE(c.session.reliable_expired_unacked, 1u);
  EXPECT_EQ(drop_count(gateway.statistics(), "reliable-too-old"), 0u);
  EXPECT_NE(gateway.stats_line().find("reliable dropped too-old 0 surface-restart 0 "
                                      "expired-unacked 10,"),
            std::string::npos)
      << gateway.stats_line();

  gateway.stop();
  node.close();
  EXPECT_TRUE(test::run_until(io, [&] { return node.done(); }));
}

}  // namespace
}  // namespace canbridge::bridge
