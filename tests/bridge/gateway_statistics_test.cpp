// The gateway's statistics core on a snapshot built by hand: each frame-drop figure adds what the
// outbox and the session each dropped, the optional sections appear exactly when they have
// something to say, and the backbone table takes the links' reads and the round trip only from a
// link that is up.
#include "bridge/gateway_statistics.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <string>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

std::uint64_t drop(const RoleStatistics& s, const std::string& reason) {
  for (const DropCount& d : s.drops) {
    if (d.reason == reason) return d.count;
  }
  ADD_FAILURE() << "no drop counter " << reason;
  return 0;
}

GatewayStatsSnapshot snapshot() {
  GatewayStatsSnapshot s;
  s.name = "gw";
  s.connected = true;
  s.counters.outbox.reliable_too_old = 3;
  s.counters.session_frames_too_old = 4;
  s.counters.outbox.discarded_peer_restart = 5;
  s.counters.session_frames_peer_restart = 6;
  s.counters.malformed_payloads = 1;
  s.counters.session.malformed = 2;
  s.counters.backbone_tx_bytes = 1000;
  s.queued = 7;
  s.unacked = 8;
  s.round_trip = 1500us;
  s.links.rx_bytes = 900;
  s.links.rx_messages = 90;
  s.links.tx_writes = 9;
  s.buses.push_back({1, "vcan1", {}, true});
  s.buses.push_back({2, "vcan2", {}, false});
  return s;
}

TEST(GatewayStatistics, DropsAddTheOutboxAndTheSessionOnce) {
  const RoleStatistics s = gateway_statistics(snapshot());
  EXPECT_EQ(s.role, "gateway");
  EXPECT_EQ(drop(s, "reliable-too-old"), 7u);
  EXPECT_EQ(drop(s, "reliable-peer-restart"), 11u);
  EXPECT_EQ(drop(s, "malformed-payload"), 3u);
  EXPECT_EQ(s.backbone.peers_up, 1u);
  EXPECT_EQ(s.backbone.tx_bytes, 1000u);
  EXPECT_EQ(s.backbone.rx_bytes, 900u);
  EXPECT_EQ(s.backbone.tx_writes, 9u);
  EXPECT_EQ(s.backbone.unacked, 8u);
  ASSERT_TRUE(s.backbone.round_trip);
  EXPECT_EQ(*s.backbone.round_trip, 1500us);
  ASSERT_EQ(s.buses.size(), 2u);
  EXPECT_FALSE(s.buses[1].link_up);
}

TEST(GatewayStatistics, NoRoundTripWhileTheLinkIsDown) {
  GatewayStatsSnapshot down = snapshot();
  down.connected = false;
  const RoleStatistics s = gateway_statistics(down);
  EXPECT_EQ(s.backbone.peers_up, 0u);
  EXPECT_FALSE(s.backbone.round_trip);
}

TEST(GatewayStatistics, LineSaysWhatIsThereAndNothingElse) {
  GatewayStatsSnapshot quiet = snapshot();
  const std::string line = gateway_stats_line(quiet);
  EXPECT_NE(line.find("gateway gw: link up,"), std::string::npos) << line;
  EXPECT_NE(line.find("queued 7,"), std::string::npos) << line;
  EXPECT_NE(line.find("unacked 8,"), std::string::npos) << line;
  EXPECT_NE(line.find("reliable dropped too-old 7 surface-restart 11"), std::string::npos) << line;
  EXPECT_NE(line.find("vcan1"), std::string::npos) << line;
  EXPECT_NE(line.find("vcan2"), std::string::npos) << line;
  EXPECT_EQ(line.find("pdop packets"), std::string::npos) << line;
  EXPECT_EQ(line.find("remote requests"), std::string::npos) << line;
  EXPECT_EQ(line.find("census"), std::string::npos) << line;

  GatewayStatsSnapshot busy = snapshot();
  busy.pdop_active = true;
  busy.pdop_dropped_frames = 12;
  busy.counters.remote.requests = 2;
  busy.counters.remote.census_questions = 30;
  busy.counters.remote.census_yielded = 1;
  busy.counters.remote.census_late_answers = 1;
  const std::string busy_line = gateway_stats_line(busy);
  EXPECT_NE(busy_line.find("dropped-frames 12"), std::string::npos) << busy_line;
  EXPECT_NE(busy_line.find("remote requests 2"), std::string::npos) << busy_line;
  EXPECT_NE(busy_line.find("census questions 30 gave-way 1 late-answers 1"), std::string::npos)
      << busy_line;
}

}  // namespace
}  // namespace canbridge::bridge
