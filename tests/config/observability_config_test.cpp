// stats_endpoint: (gateway) and metrics: (both roles): what loads, the defaults without them (no
// endpoint), and every mistake reported at its line: a relative socket path, a metrics address
// that is not loopback, a missing port, an unknown key.
#include <gtest/gtest.h>

#include <string>

#include "config/loader.hpp"
#include "tests/config/fixtures.hpp"
#include "tests/support/config_problems.hpp"

namespace canbridge::config {
namespace {

using test::dump;
using test::has;
using test::problems_of;

using test::kConfigFixtures;

TEST(ObservabilityConfig, GatewayStatsEndpointAndMetricsLoad) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_observability.yaml");
  EXPECT_EQ(g.stats_endpoint, "/run/canbridge/gateway.sock");
  ASSERT_TRUE(g.metrics);
  EXPECT_EQ(g.metrics->listen.host, "127.0.0.1");
  EXPECT_EQ(g.metrics->listen.port, 9464);
}

TEST(ObservabilityConfig, OffWithoutTheKeys) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_remote.yaml");
  EXPECT_TRUE(g.stats_endpoint.empty());
  EXPECT_FALSE(g.metrics);
  const SurfaceOptions s = load_surface(kConfigFixtures + "surface_remote.yaml");
  EXPECT_FALSE(s.metrics);
}

TEST(ObservabilityConfig, LocalhostAndIpv6LoopbackAreLoopback) {
  const SurfaceOptions s = parse_surface(
      "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
      "gateways: [{name: g, modules: [1]}]\nmetrics: {listen: 'localhost:9000'}\n",
      "s.yaml");
  ASSERT_TRUE(s.metrics);
  EXPECT_EQ(s.metrics->listen.host, "127.0.0.1");
  const SurfaceOptions v6 = parse_surface(
      "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
      "gateways: [{name: g, modules: [1]}]\nmetrics: {listen: '[::1]:9000'}\n",
      "s.yaml");
  ASSERT_TRUE(v6.metrics);
  EXPECT_EQ(v6.metrics->listen.host, "::1");
}

TEST(ObservabilityConfig, EveryMistakeIsReportedAtItsLine) {
  const auto ps =
      problems_of([] { load_gateway(kConfigFixtures + "gateway_observability_bad.yaml"); });
  EXPECT_TRUE(has(ps, 7, "stats_endpoint", "absolute path")) << dump(ps);
  EXPECT_TRUE(has(ps, 9, "metrics.listen", "not a loopback address")) << dump(ps);
  EXPECT_TRUE(has(ps, 10, "metrics.path", "")) << dump(ps);
  EXPECT_EQ(ps.size(), 3u) << dump(ps);
  const auto surface =
      problems_of([] { load_surface(kConfigFixtures + "surface_observability_bad.yaml"); });
  EXPECT_TRUE(has(surface, 6, "metrics.listen", "host:port")) << dump(surface);
  EXPECT_EQ(surface.size(), 1u) << dump(surface);
}

}  // namespace
}  // namespace canbridge::config
