#include <gtest/gtest.h>

#include <algorithm>

#include "config/loader.hpp"
#include "tests/support/config_problems.hpp"

namespace canbridge::config {
namespace {

const std::string kConfigDir = CANBRIDGE_SOURCE_DIR "/config/";
const std::string kFixtures = CANBRIDGE_SOURCE_DIR "/tests/config/fixtures/";

using test::dump;
using test::has;
using test::problems_of;

TEST(Config, SampleGatewayLoads) {
  const GatewayOptions g = load_gateway(kConfigDir + "gateway.yaml");
  EXPECT_EQ(g.connect.to_string(), "127.0.0.1:7000");
  ASSERT_EQ(g.modules.size(), 2u);
  EXPECT_EQ(g.modules[0].bus, "vcan1");
  EXPECT_EQ(g.modules[1].nodes.front(), (std::pair<std::uint8_t, std::uint8_t>{1, 65}));
  EXPECT_EQ(g.log.stats_interval, std::chrono::seconds(10));
}

TEST(Config, SampleSurfaceLoads) {
  const SurfaceOptions s = load_surface(kConfigDir + "surface.yaml");
  EXPECT_EQ(s.bus, "vcan0");
  EXPECT_EQ(s.listen.port, 7000);
}

TEST(Config, EveryProblemOfABadFileIsReportedWithLineAndField) {
  auto ps = problems_of([] { load_gateway(kFixtures + "gateway_bad.yaml"); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 3, "backbone.connect", "must be host:port")) << all;
  EXPECT_TRUE(has(ps, 5, "backbone.reconnect_max_ms", "reconnect_min_ms")) << all;
  EXPECT_TRUE(has(ps, 9, "modules[1].id", "no default node map")) << all;
  EXPECT_TRUE(has(ps, 10, "modules[1].bus", "used by two modules")) << all;
  EXPECT_TRUE(has(ps, 13, "modules[2].nodes.2", "out of range 1..127")) << all;
  EXPECT_TRUE(has(ps, 14, "modules[3].id", "missing")) << all;
  EXPECT_TRUE(has(ps, 15, "modules[3].speed", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 17, "log.level", "'loud'")) << all;
  EXPECT_EQ(ps.size(), 8u) << all;
  EXPECT_NE(std::string(ConfigError(ps).what()).find("gateway_bad.yaml:17: log.level"),
            std::string::npos);
}

TEST(Config, OverlappingSurfaceIdsNameBothOwners) {
  auto ps = problems_of([] { load_gateway(kFixtures + "gateway_overlap.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_EQ(ps[0].line, 9);
  EXPECT_NE(
      ps[0].message.find("module 4 node 6: surface node id 7 is already owned by module 0 node 7"),
      std::string::npos)
      << ps[0].message;
}

TEST(Config, AKeyGivenTwiceIsRefusedNotSilentlyOverwritten) {
  const auto ps = problems_of([] {
    parse_surface("role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000}\nbus: vcan1\n",
                  "twice.yaml");
  });
  EXPECT_TRUE(has(ps, 4, "bus", "given twice (first at line 2)")) << dump(ps);
}

TEST(Config, WrongRoleSyntaxErrorAndMissingFile) {
  auto role = problems_of([] { parse_surface("role: gateway\n", "x.yaml"); });
  ASSERT_EQ(role.size(), 1u);
  EXPECT_EQ(role[0].field, "role");
  auto syntax = problems_of([] { parse_gateway("role: gateway\nmodules: [\n", "y.yaml"); });
  ASSERT_EQ(syntax.size(), 1u);
  EXPECT_NE(syntax[0].message.find("YAML syntax error"), std::string::npos);
  auto missing = problems_of([] { load_surface("/nonexistent/surface.yaml"); });
  ASSERT_EQ(missing.size(), 1u);
  EXPECT_EQ(missing[0].message, "cannot open the file");
  auto empty = problems_of([] { parse_surface("role: surface\n", "z.yaml"); });
  EXPECT_EQ(empty.size(), 2u) << dump(empty);  // bus and backbone
}

}  // namespace
}  // namespace canbridge::config
