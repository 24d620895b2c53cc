// command_endpoint:, networks: (surface) and remote: (gateway): what loads, the defaults without
// them, and every mistake reported at its file, line and field. Token files are made at run time
// (never committed), private like key files.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "config/loader.hpp"
#include "config/remote_access_reader.hpp"
#include "tests/config/fixtures.hpp"
#include "tests/support/config_problems.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge::config {
namespace {

using test::dump;
using test::has;
using test::problems_of;

using test::kConfigFixtures;

TEST(RemoteConfig, SurfaceEndpointAndNetworksLoad) {
  const SurfaceOptions s = load_surface(kConfigFixtures + "surface_remote.yaml");
  ASSERT_TRUE(s.command_endpoint);
  EXPECT_EQ(s.command_endpoint->unix_socket, "/tmp/canbridge-test/surface.sock");
  EXPECT_EQ(s.command_endpoint->tcp_port, 0u);
  EXPECT_EQ(s.command_endpoint->tcp_address, "127.0.0.1");
  EXPECT_EQ(s.command_endpoint->sdo_timeout, std::chrono::milliseconds(2500));
  EXPECT_TRUE(s.command_endpoint->sdo_block);
  EXPECT_FALSE(s.command_endpoint->error_detail);
  EXPECT_EQ(s.command_endpoint->max_clients, 4u);
  EXPECT_TRUE(s.command_endpoint->clients.empty());
  using Net = std::pair<std::uint32_t, std::uint32_t>;
  EXPECT_EQ(s.remote.networks, (std::vector<Net>{{1, 10}, {3, 30}}));
}

TEST(RemoteConfig, WithoutTheBlocksNoEndpointAndDefaultNetworks) {
  const SurfaceOptions s = load_surface(kConfigFixtures + "surface_pdop.yaml");
  EXPECT_FALSE(s.command_endpoint);
  EXPECT_TRUE(s.remote.networks.empty());
  // An empty block: the endpoint with every default.
  const SurfaceOptions d = parse_surface(
      "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
      "gateways: [{name: g, modules: [1]}]\ncommand_endpoint: {}\n",
      "d.yaml");
  ASSERT_TRUE(d.command_endpoint);
  EXPECT_EQ(d.command_endpoint->unix_socket, "/run/canbridge/surface.sock");
  EXPECT_EQ(d.command_endpoint->sdo_timeout, std::chrono::milliseconds(500));  // as canopend
  EXPECT_FALSE(d.command_endpoint->sdo_block);
  EXPECT_TRUE(d.command_endpoint->error_detail);
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_profiles.yaml");
  EXPECT_EQ(g.remote.sdo_timeout, std::chrono::milliseconds(1000));
  EXPECT_EQ(g.remote.flash_block_size, 127u);
}

TEST(RemoteConfig, EveryEndpointAndNetworkMistakeIsReportedAtItsLine) {
  const auto ps = problems_of([] { load_surface(kConfigFixtures + "surface_remote_bad.yaml"); });
  EXPECT_TRUE(has(ps, 9, "command_endpoint.unix_socket", "absolute path")) << dump(ps);
  EXPECT_TRUE(has(ps, 10, "command_endpoint.tcp_port", "needs clients")) << dump(ps);
  EXPECT_TRUE(has(ps, 11, "command_endpoint.tcp_address", "not a loopback address")) << dump(ps);
  EXPECT_TRUE(has(ps, 12, "command_endpoint.sdo_timeout_ms", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 13, "command_endpoint.sdo_block", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 14, "command_endpoint.colour", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 16, "networks[0].module", "not a module of any gateway")) << dump(ps);
  EXPECT_TRUE(has(ps, 17, "networks[1].net", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 19, "networks[3].module", "networks[2] already")) << dump(ps);
  EXPECT_TRUE(has(ps, 18, "networks[2].net", "both module 1's and module 2's")) << dump(ps);
  EXPECT_EQ(ps.size(), 10u) << dump(ps);
}

TEST(RemoteConfig, ADefaultNetworkClashingWithAListedOneIsNamed) {
  // Module 2's default network is 3, which module 1 takes explicitly.
  const auto ps = problems_of([] {
    parse_surface(
        "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
        "gateways: [{name: g, modules: [1, 2]}]\n"  // 4
        "networks:\n"                               // 5
        "  - {module: 1, net: 3}\n",                // 6
        "n.yaml");
  });
  EXPECT_TRUE(has(ps, 6, "networks[0].net", "network 3 would be both module 1's and module 2's"))
      << dump(ps);
}

TEST(RemoteConfig, GatewayRemoteLoadsAndChecksRanges) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_remote.yaml");
  EXPECT_EQ(g.remote.sdo_timeout, std::chrono::milliseconds(1500));
  EXPECT_EQ(g.remote.flash_block_size, 64u);
  EXPECT_EQ(g.remote.flash_answer_timeout, std::chrono::milliseconds(30000));
  EXPECT_EQ(g.remote.boot_timeout, std::chrono::milliseconds(8000));
  EXPECT_EQ(g.remote.max_queued_per_node, 16u);
  const auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_remote_bad.yaml"); });
  EXPECT_TRUE(has(ps, 8, "remote.sdo_timeout_ms", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 9, "remote.flash_block_size", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 10, "remote.boot_time_ms", "")) << dump(ps);
  EXPECT_EQ(ps.size(), 3u) << dump(ps);
}

// Clients name token files as @KEYS@/name; the fixture makes them and substitutes.
class TokenConfig : public ::testing::Test {
 protected:
  SurfaceOptions surface(std::string clients) const {
    for (auto at = clients.find("@KEYS@"); at != std::string::npos;
         at = clients.find("@KEYS@", at)) {
      clients.replace(at, 6, keys_.path());
    }
    return parse_surface(
        "role: surface\n"                                            // 1
        "bus: vcan0\n"                                               // 2
        "backbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"  // 3
        "gateways: [{name: g, modules: [1]}]\n"                      // 4
        "command_endpoint:\n"                                        // 5
        "  tcp_port: 7100\n"                                         // 6
        "  clients:\n" +                                             // 7
            clients,                                                 // 8..
        "t.yaml");
  }
  test::TempKeyDir keys_;
};

TEST_F(TokenConfig, ClientsGetTheirTokensAndRoles) {
  keys_.file("bench.token", "# the bench's token\n\n  0123456789abcdef0123  \n");
  keys_.file("viewer.token", "fedcba9876543210fedcba\n", 0400);
  const SurfaceOptions s = surface(
      "    - {name: bench, role: control, token_file: @KEYS@/bench.token}\n"
      "    - {name: viewer, role: monitor, token_file: @KEYS@/viewer.token}\n");
  ASSERT_TRUE(s.command_endpoint);
  ASSERT_EQ(s.command_endpoint->clients.size(), 2u);
  EXPECT_EQ(s.command_endpoint->tcp_port, 7100u);
  EXPECT_EQ(s.command_endpoint->clients[0].name, "bench");
  EXPECT_EQ(s.command_endpoint->clients[0].token, "0123456789abcdef0123");
  EXPECT_EQ(s.command_endpoint->clients[0].role, bridge::EndpointRole::control);
  EXPECT_EQ(s.command_endpoint->clients[1].token, "fedcba9876543210fedcba");
  EXPECT_EQ(s.command_endpoint->clients[1].role, bridge::EndpointRole::monitor);
}

TEST_F(TokenConfig, TokenFilesAreCheckedLikeKeyFiles) {
  keys_.file("open.token", "0123456789abcdef0123\n", 0644);
  keys_.file("short.token", "abc\n");
  keys_.file("a.token", "0123456789abcdef0123\n");
  keys_.file("b.token", "0123456789abcdef0123\n");
  const auto ps = problems_of([&] {
    surface(
        "    - {name: a, role: monitor, token_file: @KEYS@/open.token}\n"     // 8
        "    - {name: b, role: control, token_file: @KEYS@/missing.token}\n"  // 9
        "    - {name: c, role: control, token_file: @KEYS@/short.token}\n"    // 10
        "    - {name: d, role: admin, token_file: @KEYS@/a.token}\n"          // 11
        "    - {name: e, role: monitor, token_file: @KEYS@/a.token}\n"        // 12
        "    - {name: f, role: monitor, token_file: @KEYS@/b.token}\n"        // 13
        "    - {name: e, role: monitor, token_file: @KEYS@/a.token}\n"        // 14
        "    - {name: g, role: monitor}\n");                                  // 15
  });
  EXPECT_TRUE(has(ps, 8, "command_endpoint.clients[0].token_file", "")) << dump(ps);
  EXPECT_TRUE(has(ps, 9, "command_endpoint.clients[1].token_file", "cannot be read")) << dump(ps);
  EXPECT_TRUE(has(ps, 10, "command_endpoint.clients[2].token_file", "at least 16")) << dump(ps);
  EXPECT_TRUE(has(ps, 11, "command_endpoint.clients[3].role", "'admin' is not one of")) << dump(ps);
  EXPECT_TRUE(has(ps, 13, "command_endpoint.clients[5].token_file", "the same token as client 'e'"))
      << dump(ps);
  EXPECT_TRUE(has(ps, 14, "command_endpoint.clients[6].name", "another client")) << dump(ps);
  EXPECT_TRUE(has(ps, 15, "command_endpoint.clients[7].token_file", "missing")) << dump(ps);
}

TEST_F(TokenConfig, AWorldReadableTokenIsRefusedWithTheKeyFileRule) {
  const std::string path = keys_.file("open.token", "0123456789abcdef0123\n", 0640);
  const TokenFileResult r = read_token_file(path);
  EXPECT_TRUE(r.token.empty());
  EXPECT_NE(r.problem.find(path), std::string::npos) << r.problem;
  EXPECT_TRUE(read_token_file(keys_.file("ok.token", "0123456789abcdef0123\n")).problem.empty());
}

}  // namespace
}  // namespace canbridge::config
