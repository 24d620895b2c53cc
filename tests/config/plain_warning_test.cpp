// The start-up warning of a plain (unauthenticated) backbone: given for plain only, naming what
// is exposed.
#include "app/plain_warning.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

TEST(PlainWarning, SurfaceNamesItsListenerLinesAndBus) {
  config::SurfaceOptions s;
  s.name = "bench";
  s.bus = "vcan0";
  s.listen = {"127.0.0.1", 7000};
  s.serial.push_back({"/dev/ttyS1", 115200, false, "g"});
  s.auth.mode = config::AuthMode::plain;
  const auto warning = plain_warning(s);
  ASSERT_TRUE(warning);
  EXPECT_NE(warning->find("surface bench: backbone is NOT authenticated (auth mode plain, "
                          "listening on 127.0.0.1:7000, serial line /dev/ttyS1): any peer that "
                          "reaches it may put frames on bus vcan0"),
            std::string::npos)
      << *warning;
  s.auth.mode = config::AuthMode::psk;
  EXPECT_FALSE(plain_warning(s));
  s.auth.mode = config::AuthMode::certificates;
  EXPECT_FALSE(plain_warning(s));
}

TEST(PlainWarning, GatewayNamesItsLink) {
  config::GatewayOptions g;
  g.name = "tool";
  g.connect = {"localhost", 7000};
  g.auth.mode = config::AuthMode::plain;
  ASSERT_TRUE(plain_warning(g));
  EXPECT_NE(plain_warning(g)->find("gateway tool: backbone is NOT authenticated (auth mode plain, "
                                   "tcp localhost:7000)"),
            std::string::npos);
  g.auth.mode = config::AuthMode::psk;
  EXPECT_FALSE(plain_warning(g));
}

}  // namespace
}  // namespace canbridge::bridge
