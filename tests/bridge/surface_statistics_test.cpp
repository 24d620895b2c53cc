// The surface's statistics core on a snapshot built by hand: the withdrawn SDO requests add the
// queued and the unacknowledged ones, drops from a gateway that sent what is not its own are
// named by gateway, and the backbone table takes the links' bytes both ways.
#include "bridge/surface_statistics.hpp"

#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <string>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

SurfaceStatsSnapshot snapshot() {
  SurfaceStatsSnapshot s;
  s.name = "sf";
  s.gateways_up = 1;
  s.gateways_configured = 2;
  s.gateways_known = 2;
  s.bus = {0, "vcan0", {}, true};
  s.links.tx_bytes = 500;
  s.links.rx_bytes = 700;
  s.unacked = 3;
  s.round_trip = 2ms;
  s.counters.outbox.sdo_requests_withdrawn = 4;
  s.counters.sdo_requests_withdrawn_unacked = 5;
  s.counters.sdo_guard.withdrawn_pending = 9;
  s.counters.sdo_guard.answers_recovered = 2;
  return s;
}

TEST(SurfaceStatistics, TableCarriesLinksRoundTripAndSdoOutcomes) {
  const RoleStatistics s = surface_statistics(snapshot());
  EXPECT_EQ(s.role, "surface");
  EXPECT_EQ(s.backbone.peers_up, 1u);
  EXPECT_EQ(s.backbone.peers_known, 2u);
  EXPECT_EQ(s.backbone.tx_bytes, 500u);
  EXPECT_EQ(s.backbone.rx_bytes, 700u);
  EXPECT_EQ(s.backbone.unacked, 3u);
  ASSERT_TRUE(s.backbone.round_trip);
  EXPECT_EQ(*s.backbone.round_trip, 2000us);
  ASSERT_EQ(s.buses.size(), 1u);
  EXPECT_EQ(s.buses[0].interface, "vcan0");
  bool recovered = false;
  for (const SdoOutcomeCount& o : s.sdo_requests) {
    if (o.outcome == "answers-recovered") recovered = o.count == 2;
  }
  EXPECT_TRUE(recovered);
}

TEST(SurfaceStatistics, LineAddsWithdrawnRequestsAndNamesGatewaysThatSentWhatIsNotTheirs) {
  SurfaceStatsSnapshot s = snapshot();
  std::array<std::uint64_t, kNotItsOwnReasons> drops{};
  drops[0] = 6;
  s.counters.not_its_own_by_gateway.emplace_back("gw-b", drops);
  const std::string line = surface_stats_line(s);
  EXPECT_NE(line.find("surface sf: 1/2 gateway(s) up,"), std::string::npos) << line;
  EXPECT_NE(line.find("(withdrawn 9: pending 9"), std::string::npos) << line;
  EXPECT_NE(line.find("answers recovered 2,"), std::string::npos) << line;
  EXPECT_NE(line.find("not-its-own from 'gw-b': " +
                      std::string(to_string(static_cast<NotItsOwn>(0))) + " 6"),
            std::string::npos)
      << line;
  EXPECT_NE(line.find("vcan0"), std::string::npos) << line;
}

}  // namespace
}  // namespace canbridge::bridge
