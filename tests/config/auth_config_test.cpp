// backbone.auth, backbone.admission, gateways: and serial[].gateway: what loads, and every
// mistake reported at its file, line and field. Key files are made at run time (never committed).
#include <gtest/gtest.h>

#include <ostream>
#include <string>
#include <vector>

#include "config/backbone_auth_reader.hpp"
#include "config/loader.hpp"
#include "tests/support/config_problems.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge::config {
namespace {

using test::dump;
using test::has;
using test::problems_of;

// Configs name key files as @KEYS@/name; the fixture makes them (mode 600) and substitutes.
class AuthConfig : public ::testing::Test {
 protected:
  AuthConfig() {
    keys_.key("tool.key");
    keys_.key("probe.key");
    keys_.key("gw.key");
    keys_.file("surface.crt", "-----BEGIN CERTIFICATE-----\n");
    keys_.file("ca.crt", "-----BEGIN CERTIFICATE-----\n");
    keys_.file("surface.key.pem", "-----BEGIN PRIVATE KEY-----\n");
  }

  std::string with_keys(std::string yaml) const {
    for (auto at = yaml.find("@KEYS@"); at != std::string::npos; at = yaml.find("@KEYS@", at)) {
      yaml.replace(at, 6, keys_.path());
    }
    return yaml;
  }
  SurfaceOptions surface(const std::string& yaml) const {
    return parse_surface(with_keys(yaml), "s.yaml");
  }
  GatewayOptions gateway(const std::string& yaml) const {
    return parse_gateway(with_keys(yaml), "g.yaml");
  }
  std::vector<ConfigProblem> surface_problems(const std::string& yaml) const {
    return problems_of([&] { surface(yaml); });
  }
  std::vector<ConfigProblem> gateway_problems(const std::string& yaml) const {
    return problems_of([&] { gateway(yaml); });
  }

  test::TempKeyDir keys_;
};

// A surface on every address with pre-shared keys: two gateways, ranges of surface ids, one of
// them on a serial line too.
const char* kPskSurface =
    "role: surface\n"                               // 1
    "bus: vcan0\n"                                  // 2
    "backbone:\n"                                   // 3
    "  listen: 0.0.0.0:7000\n"                      // 4
    "  auth: {mode: psk, mac_tag_bytes: 32}\n"      // 5
    "  admission:\n"                                // 6
    "    max_pending_handshakes: 8\n"               // 7
    "    handshake_timeout_ms: 500\n"               // 8
    "    max_links: 12\n"                           // 9
    "  serial:\n"                                   // 10
    "    - {device: /dev/ttyS1, gateway: probe}\n"  // 11
    "gateways:\n"                                   // 12
    "  - name: tool\n"                              // 13
    "    modules: [1, 2]\n"                         // 14
    "    surface_nodes: [33-63, 65, 66-70]\n"       // 15
    "    key_file: @KEYS@/tool.key\n"               // 16
    "  - name: probe\n"                             // 17
    "    modules: [7]\n"                            // 18
    "    surface_nodes: [100-102]\n"                // 19
    "    key_file: @KEYS@/probe.key\n";             // 20

TEST_F(AuthConfig, PskSurfaceLoadsItsGatewaysAdmissionAndLines) {
  const SurfaceOptions s = surface(kPskSurface);
  EXPECT_EQ(s.auth.mode, AuthMode::psk);
  EXPECT_EQ(s.auth.mac_tag_bytes, 32u);
  EXPECT_EQ(s.admission.max_pending_handshakes, 8u);
  EXPECT_EQ(s.admission.handshake_timeout, std::chrono::milliseconds(500));
  EXPECT_EQ(s.admission.max_links, 12u);
  ASSERT_EQ(s.gateways.size(), 2u);
  EXPECT_EQ(s.gateways[0].name, "tool");
  EXPECT_EQ(s.gateways[0].modules, (std::vector<std::uint32_t>{1, 2}));
  ASSERT_EQ(s.gateways[0].surface_nodes.size(), 31u + 1 + 5);
  EXPECT_EQ(s.gateways[0].surface_nodes.front(), 33);
  EXPECT_EQ(s.gateways[0].surface_nodes.back(), 70);
  EXPECT_EQ(s.gateways[0].key_file, keys_.path() + "/tool.key");
  EXPECT_EQ(s.gateways[1].surface_nodes, (std::vector<std::uint8_t>{100, 101, 102}));
  ASSERT_EQ(s.serial.size(), 1u);
  EXPECT_EQ(s.serial[0].gateway, "probe");
}

TEST_F(AuthConfig, DefaultSurfaceNodesStayEmptyForTheDefaultMapAndAdmissionKeepsItsDefaults) {
  const SurfaceOptions s = surface(
      "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: plain}}\n"
      "gateways: [{name: a, modules: [0, 3]}]\n");
  ASSERT_EQ(s.gateways.size(), 1u);
  EXPECT_TRUE(s.gateways[0].surface_nodes.empty());  // options.hpp: empty = the default mapping
  const AdmissionOptions d;
  EXPECT_EQ(s.admission.max_pending_handshakes, d.max_pending_handshakes);
  EXPECT_EQ(s.admission.handshake_timeout, d.handshake_timeout);
  EXPECT_EQ(s.admission.max_links, d.max_links);
  EXPECT_EQ(s.auth.mode, AuthMode::plain);
}

TEST_F(AuthConfig, PskGatewayLoadsItsKeyAndTheSurfaceName) {
  const GatewayOptions g = gateway(
      "role: gateway\nname: tool\nbackbone:\n  connect: surface.example:7000\n"
      "  auth: {mode: psk, key_file: @KEYS@/gw.key, surface: rig-surface, mac_tag_bytes: 16}\n"
      "modules: [{id: 1, bus: vcan1}]\n");
  EXPECT_EQ(g.auth.mode, AuthMode::psk);
  EXPECT_EQ(g.auth.key_file, keys_.path() + "/gw.key");
  EXPECT_EQ(g.auth.surface, "rig-surface");
  EXPECT_EQ(g.auth.mac_tag_bytes, 16u);
}

TEST_F(AuthConfig, CertificatesLoadOnBothRoles) {
  const std::string files =
      "certificate: @KEYS@/surface.crt, private_key: @KEYS@/surface.key.pem, ca: @KEYS@/ca.crt";
  const SurfaceOptions s = surface(
      "role: surface\nbus: vcan0\nbackbone:\n  listen: 0.0.0.0:7000\n"
      "  auth: {mode: certificates, " +
      files + "}\ngateways: [{name: tool, modules: [1]}]\n");
  EXPECT_EQ(s.auth.mode, AuthMode::certificates);
  EXPECT_EQ(s.auth.certificate_file, keys_.path() + "/surface.crt");
  EXPECT_EQ(s.auth.private_key_file, keys_.path() + "/surface.key.pem");
  EXPECT_EQ(s.auth.ca_file, keys_.path() + "/ca.crt");
  const GatewayOptions g = gateway(
      "role: gateway\nbackbone:\n  connect: 10.0.0.1:7000\n"
      "  auth: {mode: certificates, " +
      files + "}\nmodules: [{id: 1, bus: vcan1}]\n");
  EXPECT_EQ(g.auth.mode, AuthMode::certificates);
  EXPECT_TRUE(g.auth.key_file.empty());
}

TEST_F(AuthConfig, PlainLoadsOnLoopbackAndOnSerialLines) {
  for (const char* host : {"127.0.0.1", "127.1.2.3", "localhost", "[::1]"}) {
    const GatewayOptions g =
        gateway(std::string("role: gateway\nbackbone:\n  connect: '") + host +
                ":7000'\n  auth: {mode: plain}\nmodules: [{id: 1, bus: vcan1}]\n");
    EXPECT_EQ(g.auth.mode, AuthMode::plain) << host;
  }
  const SurfaceOptions s = surface(
      "role: surface\nbus: vcan0\nbackbone:\n  auth: {mode: plain}\n"
      "  serial: [{device: /dev/ttyS1}]\ngateways: [{name: a, modules: [1]}]\n");
  EXPECT_EQ(s.auth.mode, AuthMode::plain);
  EXPECT_TRUE(s.serial[0].gateway.empty());  // optional when plain
}

TEST(LoopbackHost, OnlyLoopbackAddressesAndLocalhost) {
  for (const char* host : {"127.0.0.1", "127.255.255.254", "localhost", "::1", "[::1]"}) {
    EXPECT_TRUE(is_loopback_host(host)) << host;
  }
  for (const char* host : {"0.0.0.0", "10.0.0.1", "128.0.0.1", "::", "[::]", "example.org",
                           "localhost.example.org", "::ffff:10.0.0.1", ""}) {
    EXPECT_FALSE(is_loopback_host(host)) << host;
  }
}

// One mistake per case, reported once, at its line and field.
struct BadAuthCase {
  const char* name;
  bool surface;
  std::string yaml;
  int line;
  const char* field;
  const char* text;
};

const std::string kSurfaceHead = "role: surface\nbus: vcan0\nbackbone:\n";  // lines 1-3
const std::string kGatewayHead = "role: gateway\nname: tool\nbackbone:\n";  // lines 1-3
const std::string kOneModule = "modules: [{id: 1, bus: vcan1}]\n";
const std::string kToolGateway =
    "gateways: [{name: tool, modules: [1], key_file: @KEYS@/tool.key}]\n";

std::vector<BadAuthCase> bad_auth_cases() {
  return {
      {"SurfaceWithoutAuth", true, kSurfaceHead + "  listen: 127.0.0.1:7000\n" + kToolGateway, 3,
       "backbone.auth", "missing (required): how this end proves who it is; write 'mode: psk'"},
      {"GatewayWithoutAuthSaysPlainIsForALoopbackBench", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n" + kOneModule, 3, "backbone.auth",
       "or 'mode: plain' for a bench on loopback"},
      {"AuthWithoutMode", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth: {key_file: @KEYS@/gw.key}\n" + kOneModule,
       5, "backbone.auth.mode", "missing (required): write 'mode: psk'"},
      {"UnknownMode", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth: {mode: tls}\n" + kOneModule, 5,
       "backbone.auth.mode", "'tls' is not one of psk, certificates, plain"},
      {"PlainSurfaceOnEveryAddress", true,
       kSurfaceHead + "  listen: 0.0.0.0:7000\n  auth: {mode: plain}\n" + kToolGateway, 5,
       "backbone.auth.mode",
       "plain (nothing authenticated) is allowed only on a loopback address (127.0.0.0/8, ::1, "
       "localhost) or a serial line, and backbone.listen is 0.0.0.0:7000: use mode psk or "
       "certificates"},
      {"PlainGatewayToANetworkAddress", false,
       kGatewayHead + "  connect: 192.168.1.5:7000\n  auth:\n    mode: plain\n" + kOneModule, 6,
       "backbone.auth.mode", "and backbone.connect is 192.168.1.5:7000"},
      {"PskGatewayWithoutKeyFile", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth: {mode: psk}\n" + kOneModule, 5,
       "backbone.auth.key_file",
       "missing (required) with mode psk: the file of the key this gateway shares with the "
       "surface, e.g. /etc/canbridge/keys/tool.key"},
      {"PskSurfaceGatewayWithoutKeyFile", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: psk}\n" +
           "gateways:\n  - {name: tool, modules: [1]}\n",
       7, "gateways[0].key_file", "missing (required) with mode psk"},
      {"KeyFileMissing", false,
       kGatewayHead +
           "  connect: 127.0.0.1:7000\n  auth: {mode: psk, key_file: @KEYS@/nope.key}\n" +
           kOneModule,
       5, "backbone.auth.key_file", "nope.key: cannot open: No such file or directory (make one:"},
      {"KeyFileReadableByOthers", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: psk}\n" +
           "gateways:\n  - name: tool\n    modules: [1]\n    key_file: @KEYS@/open.key\n",
       9, "gateways[0].key_file", "mode 0644 lets group or others access the key; run `chmod 600 "},
      {"KeyFileMalformed", false,
       kGatewayHead +
           "  connect: 127.0.0.1:7000\n  auth: {mode: psk, key_file: @KEYS@/short.key}\n" +
           kOneModule,
       5, "backbone.auth.key_file", "short.key"},
      {"SurfaceAuthWithAKeyFile", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth:\n    mode: psk\n" +
           "    key_file: @KEYS@/gw.key\n" + kToolGateway,
       7, "backbone.auth.key_file", "one key per gateway: give it as gateways[].key_file"},
      {"CertificatesWithoutCa", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth:\n    mode: certificates\n" +
           "    certificate: @KEYS@/surface.crt\n    private_key: @KEYS@/surface.key.pem\n" +
           kOneModule,
       5, "backbone.auth.ca", "missing (required) with mode certificates on TCP"},
      {"CertificatesPrivateKeyReadableByOthers", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth:\n    mode: certificates\n" +
           "    certificate: @KEYS@/surface.crt\n    private_key: @KEYS@/open.key\n" +
           "    ca: @KEYS@/ca.crt\n" + kOneModule,
       8, "backbone.auth.private_key", "run `chmod 600 "},
      {"CertificatesGatewayOnASerialLineNeedsAKeyFile", false,
       kGatewayHead + "  serial: {device: /dev/ttyS1}\n  auth: {mode: certificates}\n" + kOneModule,
       5, "backbone.auth.key_file", "missing (required) with mode certificates on a serial line"},
      {"MacTagBytesNot16Or32", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth: {mode: plain, mac_tag_bytes: 24}\n" +
           kOneModule,
       5, "backbone.auth.mac_tag_bytes", "24 is not 16 or 32"},
      {"SerialLineOfAnUnknownGateway", true,
       kSurfaceHead + "  auth: {mode: psk}\n  serial:\n    - device: /dev/ttyS1\n" +
           "      gateway: probe\n" + kToolGateway,
       7, "backbone.serial[0].gateway", "'probe' is not the name of a gateway in 'gateways'"},
      {"SerialLineWithoutGatewayWhenAuthenticated", true,
       kSurfaceHead + "  auth: {mode: psk}\n  serial:\n    - device: /dev/ttyS1\n" + kToolGateway,
       6, "backbone.serial[0].gateway", "missing (required) unless mode is plain"},
      {"SerialLineOfAGatewayWithoutKey", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: certificates, " +
           "certificate: @KEYS@/surface.crt, private_key: @KEYS@/surface.key.pem, " +
           "ca: @KEYS@/ca.crt}\n  serial: [{device: /dev/ttyS1, gateway: tool}]\n" +
           "gateways: [{name: tool, modules: [1]}]\n",
       6, "backbone.serial[0].gateway", "gateway 'tool' has no key_file"},
      {"TwoLinesForOneGateway", true,
       kSurfaceHead +
           "  auth: {mode: plain}\n  serial:\n    - {device: /dev/ttyS1, gateway: tool}\n" +
           "    - {device: /dev/ttyS2, gateway: tool}\n" + kToolGateway,
       7, "backbone.serial[1].gateway",
       "also served by backbone.serial[0]: a gateway has one line"},
      {"NoGateways", true, kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\n", 1,
       "gateways", "missing (required): the gateways this surface accepts"},
      {"EmptyGateways", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways: []\n", 6,
       "gateways", "must be a non-empty list"},
      {"GatewayNamedTwice", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [1]}\n  - {name: tool, modules: [2]}\n",
       8, "gateways[1].name", "'tool' is also the name of gateways[0]"},
      {"GatewayNameNotAnIdentity", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool/1, modules: [1]}\n",
       7, "gateways[0].name", "must be 1..64 letters, digits"},
      {"ModuleClaimedByTwoGateways", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [1, 2]}\n  - name: probe\n    modules: [3, 2]\n",
       9, "gateways[1].modules[1]", "module 2 is also claimed by gateways[0]: a module has one"},
      {"ModuleIdNotAnId", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [-1]}\n",
       7, "gateways[0].modules[0]", "-1 is out of range 0..4294967294"},
      {"SurfaceNodeOutOfRange", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - name: tool\n    modules: [1]\n    surface_nodes: [33, 128]\n",
       9, "gateways[0].surface_nodes[1]", "128 is out of range 1..127"},
      {"SurfaceNodeRangeBackwards", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - name: tool\n    modules: [1]\n    surface_nodes: [63-33]\n",
       9, "gateways[0].surface_nodes[0]", "'63-33' is not a node id 1..127 or a range a-b"},
      {"SurfaceNodeRangeToZero", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - name: tool\n    modules: [1]\n    surface_nodes: [0-5]\n",
       9, "gateways[0].surface_nodes[0]", "'0-5' is not a node id 1..127"},
      {"SurfaceNodesOverlapAcrossGateways", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [1], surface_nodes: [33-40]}\n" +
           "  - name: probe\n    modules: [7]\n    surface_nodes: [38-45, 33]\n",
       10, "gateways[1].surface_nodes",
       "surface node ids 33, 38-40 are also claimed by gateways[0]"},
      {"ExplicitNodesOverlapADefaultMap", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [1]}\n" +
           "  - {name: probe, modules: [7], surface_nodes: [63-64]}\n",
       8, "gateways[1].surface_nodes", "surface node id 63 is also claimed by gateways[0]"},
      {"SurfaceNodeListedTwice", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - {name: tool, modules: [1], surface_nodes: [33-40, 35]}\n",
       7, "gateways[0].surface_nodes", "node id 35 is listed twice"},
      {"ModuleWithoutADefaultMapNeedsSurfaceNodes", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\ngateways:\n" +
           "  - name: tool\n    modules: [7]\n",
       8, "gateways[0].surface_nodes", "module 7 has no default surface node ids"},
      {"AdmissionPendingZero", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\n" +
           "  admission: {max_pending_handshakes: 0}\n" + kToolGateway,
       6, "backbone.admission.max_pending_handshakes", "0 is out of range 1..65536"},
      {"AdmissionTimeoutZero", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\n  admission:\n" +
           "    handshake_timeout_ms: 0\n" + kToolGateway,
       7, "backbone.admission.handshake_timeout_ms", "0 is out of range 1..600000"},
      {"AdmissionUnknownKey", true,
       kSurfaceHead + "  listen: 127.0.0.1:7000\n  auth: {mode: plain}\n" +
           "  admission: {max_connections: 5}\n" + kToolGateway,
       6, "backbone.admission.max_connections", "unknown key"},
      {"GatewayRefusesAdmission", false,
       kGatewayHead + "  connect: 127.0.0.1:7000\n  auth: {mode: plain}\n" +
           "  admission: {max_links: 5}\n" + kOneModule,
       6, "backbone.admission", "unknown key"},
  };
}

void PrintTo(const BadAuthCase& c, std::ostream* os) {
  *os << c.name;
}

class BadAuthConfig : public AuthConfig, public ::testing::WithParamInterface<BadAuthCase> {};

TEST_P(BadAuthConfig, ReportsTheOneProblemWithLineAndField) {
  keys_.key("open.key", 0644);
  keys_.file("short.key", "0123abcd\n");
  const BadAuthCase& c = GetParam();
  const auto ps = c.surface ? surface_problems(c.yaml) : gateway_problems(c.yaml);
  ASSERT_EQ(ps.size(), 1u) << dump(ps) << with_keys(c.yaml);
  EXPECT_TRUE(has(ps, c.line, c.field, c.text)) << dump(ps) << with_keys(c.yaml);
  EXPECT_EQ(ps[0].file, c.surface ? "s.yaml" : "g.yaml");
}

INSTANTIATE_TEST_SUITE_P(Config, BadAuthConfig, ::testing::ValuesIn(bad_auth_cases()),
                         [](const auto& c) { return std::string(c.param.name); });

// Every auth problem at once, as with the rest of the file.
TEST_F(AuthConfig, EveryAuthProblemOfASurfaceIsReportedAtOnce) {
  const auto ps = surface_problems(
      "role: surface\n"                                        // 1
      "bus: vcan0\n"                                           // 2
      "backbone:\n"                                            // 3
      "  listen: 0.0.0.0:7000\n"                               // 4
      "  auth: {mode: plain, mac_tag_bytes: 8}\n"              // 5
      "  admission: {max_links: -1}\n"                         // 6
      "  serial: [{device: /dev/ttyS1, gateway: nope}]\n"      // 7
      "gateways:\n"                                            // 8
      "  - {name: a, modules: [1]}\n"                          // 9
      "  - {name: b, modules: [1], surface_nodes: [200]}\n");  // 10
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 5, "backbone.auth.mode", "backbone.listen is 0.0.0.0:7000")) << all;
  EXPECT_TRUE(has(ps, 5, "backbone.auth.mac_tag_bytes", "8 is not 16 or 32")) << all;
  EXPECT_TRUE(has(ps, 6, "backbone.admission.max_links", "-1 is out of range 0..65536")) << all;
  EXPECT_TRUE(has(ps, 7, "backbone.serial[0].gateway", "'nope' is not the name")) << all;
  EXPECT_TRUE(has(ps, 10, "gateways[1].modules[0]", "module 1 is also claimed by gateways[0]"))
      << all;
  EXPECT_TRUE(has(ps, 10, "gateways[1].surface_nodes[0]", "200 is out of range 1..127")) << all;
  EXPECT_EQ(ps.size(), 6u) << all;
}

}  // namespace
}  // namespace canbridge::config
