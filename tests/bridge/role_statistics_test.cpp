// The statistics core: rates between snapshots with an injected clock, and the three renderings
// (short line, JSON, Prometheus text) of a known snapshot as golden strings.
#include "bridge/role_statistics.hpp"

#include <gtest/gtest.h>

#include "bridge/statistics_text.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

RoleStatistics gateway_snapshot(std::uint64_t rx, std::uint64_t tx_bytes, std::uint64_t frames,
                                std::uint64_t batches, std::uint64_t unknown_node) {
  RoleStatistics s;
  s.role = "gateway";
  s.name = "gw";
  BusStatistics a;
  a.module = 1;
  a.interface = "vcan1";
  a.counters.rx_frames = rx;
  a.counters.tx_frames = 10;
  BusStatistics b;
  b.module = 2;
  b.interface = "vcan2";
  b.link_up = false;
  b.counters.reopens = 1;
  s.buses = {a, b};
  s.backbone.peers_up = 1;
  s.backbone.peers_known = 1;
  s.backbone.links = 1;
  s.backbone.tx_bytes = tx_bytes;
  s.backbone.rx_bytes = 500;
  s.backbone.frames_sent = frames;
  s.backbone.batches_sent = batches;
  s.backbone.round_trip = 1500us;
  s.drops = {{"untranslatable-unknown-node", unknown_node}, {"conflated", 0}};
  s.nodes.operational = 2;
  s.nodes.lost = 1;
  return s;
}

TEST(RateMeter, RatesCoverTheLastWholeIntervalOfTheInjectedClock) {
  auto now = std::chrono::steady_clock::time_point{} + 100s;
  RateMeter meter([&] { return now; });
  EXPECT_EQ(meter.rates().seconds, 0.0);  // nothing sampled yet
  meter.sample(gateway_snapshot(1000, 10000, 900, 30, 0));
  const RoleRates first = meter.rates();
  EXPECT_EQ(first.seconds, 0.0);  // one sample: no window yet
  ASSERT_EQ(first.buses.size(), 2u);
  EXPECT_EQ(first.buses[0].rx_frames, 0.0);
  now += 2s;
  meter.sample(gateway_snapshot(3000, 30000, 2900, 130, 4));
  const RoleRates r = meter.rates();
  EXPECT_DOUBLE_EQ(r.seconds, 2.0);
  ASSERT_EQ(r.buses.size(), 2u);
  EXPECT_DOUBLE_EQ(r.buses[0].rx_frames, 1000.0);
  EXPECT_DOUBLE_EQ(r.buses[0].tx_frames, 0.0);
  EXPECT_DOUBLE_EQ(r.backbone_tx_bytes, 10000.0);
  EXPECT_DOUBLE_EQ(r.backbone_frames_sent, 1000.0);
  EXPECT_DOUBLE_EQ(r.frames_per_message, 20.0);  // 2000 frames in 100 batches
  EXPECT_DOUBLE_EQ(r.drops, 2.0);
  // The next sample's window starts at this one: half a second later, half a second's rates.
  now += 500ms;
  meter.sample(gateway_snapshot(3500, 30000, 2900, 130, 4));
  EXPECT_DOUBLE_EQ(meter.rates().seconds, 0.5);
  EXPECT_DOUBLE_EQ(meter.rates().buses[0].rx_frames, 1000.0);
}

TEST(RateMeter, ACounterThatWentBackwardsIsNoNegativeRate) {
  const RoleRates r =
      rates_between(gateway_snapshot(500, 100, 0, 0, 0), gateway_snapshot(100, 50, 0, 0, 0), 1s);
  EXPECT_EQ(r.buses[0].rx_frames, 0.0);
  EXPECT_EQ(r.backbone_tx_bytes, 0.0);
  EXPECT_EQ(rates_between(gateway_snapshot(1, 1, 1, 1, 1), gateway_snapshot(2, 2, 2, 2, 2), 0s)
                .buses[0]
                .rx_frames,
            0.0);
}

RoleRates two_second_rates() {
  return rates_between(gateway_snapshot(1000, 10000, 900, 30, 0),
                       gateway_snapshot(3000, 30000, 2900, 130, 4), 2s);
}

TEST(StatisticsLine, ShortWithRatesStateDropsAndNodes) {
  EXPECT_EQ(statistics_line(gateway_snapshot(3000, 30000, 2900, 130, 4), two_second_rates()),
            "gateway gw: link up rtt 1.5 ms; module 1 bus vcan1 error-active rx 1.0k/s tx 0/s; "
            "module 2 bus vcan2 down rx 0/s tx 0/s; backbone out 10kB/s 1.0k frames/s "
            "(20.0/msg), in 0B/s 0 frames/s, resent 0; drops 4 (untranslatable-unknown-node 4); "
            "nodes 3 (2 op, 1 lost)");
}

TEST(StatisticsJson, EveryCounterAndRateOnOneLine) {
  const std::string json =
      statistics_json(gateway_snapshot(3000, 30000, 2900, 130, 4), two_second_rates());
  EXPECT_EQ(json.find('\n'), std::string::npos);
  EXPECT_EQ(
      json,
      R"({"role":"gateway","name":"gw","window_s":2.000,"buses":[)"
      R"({"module":1,"interface":"vcan1","state":"error-active","link_up":true,)"
      R"("fault_state":"error-active","rx_frames":3000,"tx_frames":10,"rx_frames_per_s":1000.0,)"
      R"("tx_frames_per_s":0.0,"rx_dropped_kernel":0,"rx_dropped_queue":0,"tx_dropped_queue":0,)"
      R"("tx_dropped_error":0,"tx_dropped_interface_lost":0,"rx_dropped_interface_lost":0,)"
      R"("tx_retries":0,"error_frames":0,"reopens":0},)"
      R"({"module":2,"interface":"vcan2","state":"down","link_up":false,)"
      R"("fault_state":"error-active","rx_frames":0,"tx_frames":0,"rx_frames_per_s":0.0,)"
      R"("tx_frames_per_s":0.0,"rx_dropped_kernel":0,"rx_dropped_queue":0,"tx_dropped_queue":0,)"
      R"("tx_dropped_error":0,"tx_dropped_interface_lost":0,"rx_dropped_interface_lost":0,)"
      R"("tx_retries":0,"error_frames":0,"reopens":1}],)"
      R"("backbone":{"peers_up":1,"peers_known":1,"links":1,"dead_links":0,"tx_bytes":30000,)"
      R"("rx_bytes":500,"tx_bytes_per_s":10000.0,"rx_bytes_per_s":0.0,"tx_writes":0,)"
      R"("rx_messages":0,"frames_sent":2900,"frames_received":0,"frames_sent_per_s":1000.0,)"
      R"("frames_received_per_s":0.0,"frames_per_message":20.0,"batches_sent":130,)"
      R"("reliable_sent":0,"reliable_resent":0,"resend_requests":0,"unacked":0,)"
      R"("round_trip_ms":1.500},)"
      R"("drops":{"total":4,"per_s":2.0,"by_reason":{"untranslatable-unknown-node":4,)"
      R"("conflated":0}},)"
      R"("nodes":{"total":3,"operational":2,"pre_operational":0,"stopped":0,"in_loader":0,)"
      R"("lost":1,"unknown":0}})");
}

TEST(StatisticsJson, StringsAreEscaped) {
  EXPECT_EQ(json_string("a\"b\\c\nd"), R"("a\"b\\c\u000ad")");
}

TEST(StatisticsPrometheus, CountersGaugesAndLabels) {
  RoleStatistics s = gateway_snapshot(3000, 30000, 2900, 130, 4);
  s.buses[0].counters.state = can::BusState::error_passive;
  const std::string text = statistics_prometheus(s);
  for (const char* expected : {
           "# TYPE canbridge_bus_frames_total counter\n",
           "canbridge_bus_frames_total{module=\"1\",bus=\"vcan1\",direction=\"rx\"} 3000\n",
           "canbridge_bus_frames_total{module=\"1\",bus=\"vcan1\",direction=\"tx\"} 10\n",
           "canbridge_bus_dropped_frames_total{module=\"2\",bus=\"vcan2\",direction=\"tx\","
           "reason=\"interface-lost\"} 0\n",
           "canbridge_bus_reopens_total{module=\"2\",bus=\"vcan2\"} 1\n",
           "# TYPE canbridge_bus_up gauge\n",
           "canbridge_bus_up{module=\"1\",bus=\"vcan1\"} 1\n",
           "canbridge_bus_up{module=\"2\",bus=\"vcan2\"} 0\n",
           "canbridge_bus_state{module=\"1\",bus=\"vcan1\",state=\"error-passive\"} 1\n",
           "canbridge_bus_state{module=\"1\",bus=\"vcan1\",state=\"error-active\"} 0\n",
           "canbridge_backbone_peers_up 1\n",
           "canbridge_backbone_bytes_total{direction=\"tx\"} 30000\n",
           "canbridge_backbone_frames_total{direction=\"tx\"} 2900\n",
           "canbridge_backbone_round_trip_seconds 0.0015\n",
           "canbridge_dropped_frames_total{reason=\"untranslatable-unknown-node\"} 4\n",
           "canbridge_nodes{state=\"lost\"} 1\n",
       }) {
    EXPECT_NE(text.find(expected), std::string::npos) << expected << "\nin:\n" << text;
  }
  // Every line is a comment or "name{labels} value": nothing the 0.0.4 parser would refuse.
  std::size_t start = 0;
  while (start < text.size()) {
    const std::size_t end = text.find('\n', start);
    ASSERT_NE(end, std::string::npos) << "the last line has no line feed";
    const std::string line = text.substr(start, end - start);
    EXPECT_TRUE(line.rfind("# HELP ", 0) == 0 || line.rfind("# TYPE ", 0) == 0 ||
                line.rfind("canbridge_", 0) == 0)
        << line;
    start = end + 1;
  }
}

// The surface's SDO request outcomes across cuts: in JSON after the drops, as a labelled
// counter in Prometheus; a gateway (no outcomes) shows neither.
TEST(StatisticsJson, TheSurfacesSdoOutcomesFollowTheDrops) {
  RoleStatistics s = gateway_snapshot(3000, 30000, 2900, 130, 4);
  EXPECT_EQ(statistics_json(s, two_second_rates()).find("sdo_requests"), std::string::npos);
  EXPECT_EQ(statistics_prometheus(s).find("canbridge_sdo_requests_total"), std::string::npos);
  s.sdo_requests = {{"aborted-link-down", 3}, {"answers-recovered", 2}};
  const std::string json = statistics_json(s, two_second_rates());
  EXPECT_NE(json.find(R"("conflated":0}},"sdo_requests":{"aborted-link-down":3,)"
                      R"("answers-recovered":2},"nodes":{)"),
            std::string::npos)
      << json;
  EXPECT_NE(statistics_prometheus(s).find(
                "canbridge_sdo_requests_total{outcome=\"answers-recovered\"} 2\n"),
            std::string::npos);
}

TEST(StatisticsPrometheus, LabelValuesAreEscaped) {
  RoleStatistics s;
  s.drops = {{"odd\"reason\\", 1}};
  EXPECT_NE(statistics_prometheus(s).find(
                "canbridge_dropped_frames_total{reason=\"odd\\\"reason\\\\\"} 1\n"),
            std::string::npos);
}

}  // namespace
}  // namespace canbridge::bridge
