// `canbridge check`: the shipped samples of both roles are valid once their key exists, a file of
// either role is recognised by its role: key, and every problem is named with exit status 2.
// The samples name vcan1..vcan4 and vcan0, which this build machine's kernel does not have: a
// check that opened an interface would fail here.
#include "app/config_check.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <sstream>
#include <string>

#include "tests/support/temp_key_dir.hpp"

namespace canbridge::bridge {
namespace {

using ::testing::HasSubstr;

struct Checked {
  int status = -1;
  std::string out;
  std::string err;
};

Checked check(const std::string& path) {
  std::ostringstream out, err;
  const int status = check_config(path, out, err);
  return {status, out.str(), err.str()};
}

std::string read(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// The shipped sample with its key file moved to `key`.
std::string sample_with_key(const std::string& sample, const std::string& key) {
  std::string text = read(std::string(CANBRIDGE_SOURCE_DIR) + "/config/" + sample);
  const std::string shipped = "/etc/canbridge/keys/tool-gateway.key";
  for (std::size_t at; (at = text.find(shipped)) != std::string::npos;) {
    text.replace(at, shipped.size(), key);
  }
  return text;
}

TEST(ConfigCheck, TheShippedSamplesOfBothRolesAreValidOnceTheirKeyExists) {
  test::TempKeyDir dir;
  const std::string key = dir.key("tool-gateway.key");
  const auto gateway = check(dir.file("gateway.yaml", sample_with_key("gateway.yaml", key)));
  EXPECT_EQ(gateway.status, 0) << gateway.err;
  EXPECT_THAT(gateway.out, HasSubstr("valid, gateway tool-gateway"));
  EXPECT_THAT(gateway.out, HasSubstr("auth psk"));
  const auto surface = check(dir.file("surface.yaml", sample_with_key("surface.yaml", key)));
  EXPECT_EQ(surface.status, 0) << surface.err;
  EXPECT_THAT(surface.out, HasSubstr("valid, surface"));
}

TEST(ConfigCheck, AMissingKeyFileIsNamed) {
  test::TempKeyDir dir;
  const std::string absent = dir.path() + "/absent.key";
  const auto gateway = check(dir.file("gateway.yaml", sample_with_key("gateway.yaml", absent)));
  EXPECT_EQ(gateway.status, 2);
  EXPECT_THAT(gateway.err, HasSubstr(absent));
  EXPECT_TRUE(gateway.out.empty());
}

TEST(ConfigCheck, EveryProblemOfABadFileIsReportedWithItsLine) {
  const std::string bad =
      std::string(CANBRIDGE_SOURCE_DIR) + "/tests/config/fixtures/gateway_bad.yaml";
  const auto result = check(bad);
  EXPECT_EQ(result.status, 2);
  EXPECT_THAT(result.err, HasSubstr(bad + ":"));
}

TEST(ConfigCheck, AFileOfNeitherRoleSaysWhatRoleMustBe) {
  test::TempKeyDir dir;
  const auto result = check(dir.file("odd.yaml", "role: bridge\nname: x\n"));
  EXPECT_EQ(result.status, 2);
  EXPECT_THAT(result.err, HasSubstr("role"));
  EXPECT_EQ(check(dir.path() + "/missing.yaml").status, 2);
}

}  // namespace
}  // namespace canbridge::bridge
