#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>

#include "config/loader.hpp"
#include "tests/config/fixtures.hpp"
#include "tests/support/config_problems.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge::config {
namespace {

const std::string kConfigDir = CANBRIDGE_SOURCE_DIR "/config/";
using test::kConfigFixtures;

using test::dump;
using test::has;
using test::problems_of;

// What a surface needs beyond its transport: the list of gateways it accepts, and (after a
// block-style backbone, as its last key) the explicit choice of a plain bench.
constexpr const char* kOneGateway = "gateways: [{name: gateway, modules: [1]}]\n";
constexpr const char* kPlainTail =
    "  auth: {mode: plain}\n"
    "gateways: [{name: gateway, modules: [1]}]\n";

// The samples give every session key at its default, documented beside it: this keeps what they
// say true when a default changes in options.hpp.
void expect_default_session(const SessionTuning& s) {
  const SessionTuning d;
  EXPECT_EQ(s.keepalive, d.keepalive);
  EXPECT_EQ(s.dead_after, d.dead_after);
  EXPECT_EQ(s.retransmit, d.retransmit);
  EXPECT_EQ(s.reliable_max_age, d.reliable_max_age);
  EXPECT_EQ(s.resend_buffer_messages, d.resend_buffer_messages);
  EXPECT_EQ(s.resend_buffer_bytes, d.resend_buffer_bytes);
  EXPECT_EQ(s.max_write_bytes, d.max_write_bytes);
  EXPECT_EQ(s.queue_reliable_frames, d.queue_reliable_frames);
  EXPECT_EQ(s.queue_process_frames, d.queue_process_frames);
  EXPECT_EQ(s.conflate_after, d.conflate_after);
}

// The samples show every pdop key at its default, like the session keys.
void expect_default_pdop(const ModuleOptions& m) {
  const ModuleOptions d;
  EXPECT_EQ(m.reassemble_pdop, d.reassemble_pdop);
  EXPECT_EQ(m.pdop_reassembly.max_packet_bytes, d.pdop_reassembly.max_packet_bytes);
  EXPECT_EQ(m.pdop_reassembly.fragment_timeout, d.pdop_reassembly.fragment_timeout);
  EXPECT_EQ(m.pdop_segmentation.max_packet_bytes, d.pdop_segmentation.max_packet_bytes);
  EXPECT_EQ(m.pdop_segmentation.window, d.pdop_segmentation.window);
  EXPECT_EQ(m.pdop_segmentation.ack_timeout, d.pdop_segmentation.ack_timeout);
  EXPECT_EQ(m.pdop_segmentation.retries, d.pdop_segmentation.retries);
  EXPECT_EQ(m.pdop_segmentation.queue_per_rpdo, d.pdop_segmentation.queue_per_rpdo);
  EXPECT_EQ(m.pdop_segmentation.max_held_bytes, d.pdop_segmentation.max_held_bytes);
}

void expect_default_relay(const bridge::RpdopRelayOptions& r) {
  const bridge::RpdopRelayOptions d;
  EXPECT_EQ(r.max_packet_bytes, d.max_packet_bytes);
  EXPECT_EQ(r.fragment_timeout, d.fragment_timeout);
  EXPECT_EQ(r.window, d.window);
  EXPECT_EQ(r.outcome_timeout, d.outcome_timeout);
}

std::string file_text(const std::string& path) {
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// The samples name their key files under /etc/canbridge/keys, which a test machine lacks: the
// tests install them (fresh keys, mode 600) in a temporary directory and point the sample there.
class ConfigSamples : public ::testing::Test {
 protected:
  ConfigSamples() { keys_.key("tool-gateway.key"); }

  std::string sample(const std::string& name) const {
    std::string text = file_text(kConfigDir + name);
    const std::string from = "/etc/canbridge/keys/";
    for (auto at = text.find(from); at != std::string::npos; at = text.find(from, at)) {
      text.replace(at, from.size(), keys_.path() + "/");
    }
    return text;
  }

  test::TempKeyDir keys_;
};

// A sample with its commented-out serial example switched on ("  # serial:" and the "  #   "
// lines after it lose their "# "), without the lines starting with `drop` (if not empty): an
// operator following the comments gets a file that loads.
std::string with_serial_example(const std::string& sample_text, const std::string& drop) {
  std::istringstream in(sample_text);
  std::string text;
  bool block = false;
  for (std::string line; std::getline(in, line);) {
    block = line.rfind("  # serial:", 0) == 0 || (block && line.rfind("  #   ", 0) == 0);
    if (block) line.erase(2, 2);
    if (drop.empty() || line.rfind(drop, 0) != 0) text += line + "\n";
  }
  return text;
}

TEST_F(ConfigSamples, SampleGatewayLoads) {
  const GatewayOptions g = parse_gateway(sample("gateway.yaml"), "gateway.yaml");
  EXPECT_EQ(g.auth.mode, AuthMode::psk);
  EXPECT_EQ(g.auth.key_file, keys_.path() + "/tool-gateway.key");
  EXPECT_EQ(g.auth.surface, "surface");
  EXPECT_EQ(g.auth.mac_tag_bytes, 16u);
  EXPECT_EQ(g.connect.to_string(), "127.0.0.1:7000");
  ASSERT_EQ(g.modules.size(), 2u);
  EXPECT_EQ(g.modules[0].bus, "vcan1");
  EXPECT_EQ(g.modules[1].nodes.front(), (std::pair<std::uint8_t, std::uint8_t>{1, 65}));
  EXPECT_EQ(g.log.stats_interval, std::chrono::seconds(10));
  EXPECT_FALSE(g.serial.has_value());
  EXPECT_TRUE(g.modules[0].conflate_pdos);
  expect_default_session(g.session);
  for (const ModuleOptions& m : g.modules) expect_default_pdop(m);
  // remote: every key shown at its default.
  const bridge::GatewayRemoteOptions r;
  EXPECT_EQ(g.remote.sdo_timeout, r.sdo_timeout);
  EXPECT_EQ(g.remote.flash_block_size, r.flash_block_size);
  EXPECT_EQ(g.remote.flash_answer_timeout, r.flash_answer_timeout);
  EXPECT_EQ(g.remote.boot_timeout, r.boot_timeout);
  EXPECT_EQ(g.remote.max_queued_per_node, r.max_queued_per_node);
}

TEST_F(ConfigSamples, SampleSurfaceLoads) {
  const SurfaceOptions s = parse_surface(sample("surface.yaml"), "surface.yaml");
  EXPECT_EQ(s.auth.mode, AuthMode::psk);
  EXPECT_EQ(s.listen.host, "127.0.0.1");
  ASSERT_EQ(s.gateways.size(), 1u);
  EXPECT_EQ(s.gateways[0].name, "tool-gateway");  // gateway.yaml's name and modules
  EXPECT_EQ(s.gateways[0].modules, (std::vector<std::uint32_t>{1, 2}));
  EXPECT_EQ(s.gateways[0].surface_nodes.size(), 62u);
  EXPECT_EQ(s.gateways[0].key_file, keys_.path() + "/tool-gateway.key");
  const AdmissionOptions a;  // the sample shows every admission key at its default
  EXPECT_EQ(s.admission.max_pending_handshakes, a.max_pending_handshakes);
  EXPECT_EQ(s.admission.handshake_timeout, a.handshake_timeout);
  EXPECT_EQ(s.admission.max_links, a.max_links);
  EXPECT_EQ(s.bus, "vcan0");
  EXPECT_EQ(s.listen.port, 7000);
  EXPECT_TRUE(s.serial.empty());
  EXPECT_TRUE(s.conflate_pdos);
  expect_default_session(s.session);
  expect_default_relay(s.rpdop_relay);
  // The block is given (with every key at its default), not merely absent.
  EXPECT_NE(file_text(kConfigDir + "surface.yaml").find("\npdop:\n  # "), std::string::npos);
  // command_endpoint: every key shown at its default, the TCP clients commented out.
  ASSERT_TRUE(s.command_endpoint);
  const bridge::CommandEndpointOptions e;
  EXPECT_EQ(s.command_endpoint->unix_socket, "/run/canbridge/surface.sock");
  EXPECT_EQ(s.command_endpoint->tcp_port, e.tcp_port);
  EXPECT_EQ(s.command_endpoint->tcp_address, e.tcp_address);
  EXPECT_EQ(s.command_endpoint->sdo_timeout, e.sdo_timeout);
  EXPECT_EQ(s.command_endpoint->sdo_block, e.sdo_block);
  EXPECT_EQ(s.command_endpoint->max_clients, e.max_clients);
  EXPECT_EQ(s.command_endpoint->monitor_queue_frames, e.monitor_queue_frames);
  EXPECT_TRUE(s.remote.networks.empty());
}

// The commented networks: example, switched on, loads as it says.
TEST_F(ConfigSamples, SampleNetworksExampleLoadsWhenUncommented) {
  std::string text = sample("surface.yaml");
  const std::string from =
      "# networks:\n#   - module: 1\n#     net: 2\n#   - module: 2\n#     net: 3\n";
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, from.size(),
               "networks:\n  - module: 1\n    net: 2\n  - module: 2\n    net: 3\n");
  const SurfaceOptions s = parse_surface(text, "surface.yaml (networks example)");
  using Net = std::pair<std::uint32_t, std::uint32_t>;
  EXPECT_EQ(s.remote.networks, (std::vector<Net>{{1, 2}, {2, 3}}));
}

// The sample's commented-out pdop module, uncommented under a minimal header (it does not fit
// beside the sample's other modules, as its comment says): an operator copying it gets a module
// that loads, with every pdop key at the default the comments state.
TEST(Config, SamplePdopModuleExampleLoadsWhenUncommented) {
  std::ifstream in(kConfigDir + "gateway.yaml");
  std::string modules;
  bool block = false;
  for (std::string line; std::getline(in, line);) {
    block = line.rfind("  # - id: 3", 0) == 0 || (block && line.rfind("  #   ", 0) == 0);
    if (block) modules += line.erase(2, 2) + "\n";
  }
  ASSERT_NE(modules.find("\n    pdop:\n"), std::string::npos) << modules;
  ASSERT_NE(modules.find("      max_held_bytes: "), std::string::npos) << modules;
  const GatewayOptions g = parse_gateway(
      "role: gateway\nbackbone:\n  connect: 127.0.0.1:7000\n  auth: {mode: plain}\n"
      "modules:\n" +
          modules,
      "gateway.yaml (pdop example)");
  ASSERT_EQ(g.modules.size(), 1u);
  EXPECT_EQ(g.modules[0].profile, bridge::IdProfile::pdop);
  expect_default_pdop(g.modules[0]);
}

TEST(Config, PdopBlockSetsEveryLimitOfAPdopModule) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_pdop.yaml");
  ASSERT_EQ(g.modules.size(), 2u);
  const ModuleOptions& m = g.modules[0];
  EXPECT_FALSE(m.reassemble_pdop);
  EXPECT_EQ(m.pdop_reassembly.max_packet_bytes, 65536u);
  EXPECT_EQ(m.pdop_segmentation.max_packet_bytes, 65536u);
  EXPECT_EQ(m.pdop_reassembly.fragment_timeout, std::chrono::milliseconds(250));
  EXPECT_EQ(m.pdop_segmentation.window, 16u);
  EXPECT_EQ(m.pdop_segmentation.ack_timeout, std::chrono::milliseconds(40));
  EXPECT_EQ(m.pdop_segmentation.retries, 0u);
  EXPECT_EQ(m.pdop_segmentation.queue_per_rpdo, 0u);
  EXPECT_EQ(m.pdop_segmentation.max_held_bytes, 131072u);
  // Without a block: the defaults of docs/pdop.md section 5.
  EXPECT_EQ(g.modules[1].profile, bridge::IdProfile::pdop);
  expect_default_pdop(g.modules[1]);
  EXPECT_TRUE(g.modules[1].reassemble_pdop);
  EXPECT_EQ(g.modules[1].pdop_reassembly.max_packet_bytes, 4096u);
  EXPECT_EQ(g.modules[1].pdop_reassembly.fragment_timeout, std::chrono::milliseconds(100));
  EXPECT_EQ(g.modules[1].pdop_segmentation.window, 4u);
  EXPECT_EQ(g.modules[1].pdop_segmentation.ack_timeout, std::chrono::milliseconds(100));
  EXPECT_EQ(g.modules[1].pdop_segmentation.retries, 3u);
  EXPECT_EQ(g.modules[1].pdop_segmentation.queue_per_rpdo, 8u);
  EXPECT_EQ(g.modules[1].pdop_segmentation.max_held_bytes, 1u << 20);
}

TEST(Config, SurfacePdopBlockSetsTheRelayLimits) {
  const SurfaceOptions s = load_surface(kConfigFixtures + "surface_pdop.yaml");
  EXPECT_EQ(s.rpdop_relay.max_packet_bytes, 8192u);
  EXPECT_EQ(s.rpdop_relay.fragment_timeout, std::chrono::milliseconds(500));
  EXPECT_EQ(s.rpdop_relay.window, 8u);
  EXPECT_EQ(s.rpdop_relay.outcome_timeout, std::chrono::milliseconds(30000));
  // Without a block: the relay's defaults.
  const SurfaceOptions d = parse_surface(
      "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: "
      "plain}}\n" +
          std::string(kOneGateway),
      "d.yaml");
  EXPECT_EQ(d.rpdop_relay.max_packet_bytes, 4096u);
  EXPECT_EQ(d.rpdop_relay.fragment_timeout, std::chrono::milliseconds(200));
  EXPECT_EQ(d.rpdop_relay.window, 4u);
  EXPECT_EQ(d.rpdop_relay.outcome_timeout, std::chrono::milliseconds(10000));
}

// As shipped, the samples ask for their key files by line, field and path, and for nothing else:
// what an operator sees before installing keys (docs/security.md).
TEST(Config, SamplesAsShippedAskOnlyForTheirKeyFiles) {
  if (::access("/etc/canbridge/keys/tool-gateway.key", F_OK) == 0) GTEST_SKIP() << "keys installed";
  const auto g = problems_of([] { load_gateway(kConfigDir + "gateway.yaml"); });
  ASSERT_EQ(g.size(), 1u) << dump(g);
  EXPECT_EQ(g[0].field, "backbone.auth.key_file");
  EXPECT_NE(g[0].message.find("/etc/canbridge/keys/tool-gateway.key: cannot open"),
            std::string::npos)
      << dump(g);
  const auto s = problems_of([] { load_surface(kConfigDir + "surface.yaml"); });
  ASSERT_EQ(s.size(), 1u) << dump(s);
  EXPECT_EQ(s[0].field, "gateways[0].key_file");
  EXPECT_NE(s[0].message.find("/etc/canbridge/keys/tool-gateway.key: cannot open"),
            std::string::npos)
      << dump(s);
}

TEST_F(ConfigSamples, SampleSerialExamplesLoadWhenUncommented) {
  const std::string gateway_text = with_serial_example(sample("gateway.yaml"), "  connect:");
  ASSERT_NE(gateway_text.find("\n  serial:\n"), std::string::npos) << gateway_text;
  const GatewayOptions g = parse_gateway(gateway_text, "gateway.yaml (serial example)");
  ASSERT_TRUE(g.serial.has_value());
  EXPECT_EQ(g.serial->device, "/dev/ttyS1");
  EXPECT_EQ(g.serial->baud, 115200u);
  EXPECT_FALSE(g.serial->hardware_flow_control);

  const std::string surface_text = with_serial_example(sample("surface.yaml"), "");
  const SurfaceOptions s = parse_surface(surface_text, "surface.yaml (serial example)");
  EXPECT_EQ(s.listen.port, 7000);
  ASSERT_EQ(s.serial.size(), 1u) << surface_text;
  EXPECT_EQ(s.serial[0].device, "/dev/ttyUSB0");
  EXPECT_EQ(s.serial[0].baud, 460800u);
  EXPECT_TRUE(s.serial[0].hardware_flow_control);
  EXPECT_EQ(s.serial[0].gateway, "tool-gateway");
}

TEST(Config, SerialGatewayLoads) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_serial.yaml");
  ASSERT_TRUE(g.serial.has_value());
  EXPECT_EQ(g.serial->device, "/dev/ttyS1");
  EXPECT_EQ(g.serial->baud, 115200u);
  EXPECT_TRUE(g.serial->hardware_flow_control);
  EXPECT_EQ(g.connect.host, "");  // no TCP endpoint
  EXPECT_EQ(g.reconnect_min, std::chrono::milliseconds(200));
  EXPECT_EQ(g.reconnect_max, std::chrono::milliseconds(2000));
  EXPECT_EQ(g.session.keepalive, std::chrono::milliseconds(1000));
  EXPECT_EQ(g.session.dead_after, std::chrono::milliseconds(5000));
  EXPECT_EQ(g.session.retransmit, std::chrono::milliseconds(3000));
  EXPECT_EQ(g.session.reliable_max_age, std::chrono::milliseconds(6000));
  EXPECT_EQ(g.session.resend_buffer_messages, 256u);
  EXPECT_EQ(g.session.resend_buffer_bytes, 65536u);
  EXPECT_EQ(g.session.max_write_bytes, 512u);
  EXPECT_EQ(g.session.queue_reliable_frames, 4096u);
  EXPECT_EQ(g.session.queue_process_frames, 1024u);
  EXPECT_EQ(g.session.conflate_after, std::chrono::milliseconds(2000));
  ASSERT_EQ(g.modules.size(), 2u);
  EXPECT_TRUE(g.modules[0].conflate_pdos);
  EXPECT_FALSE(g.modules[1].conflate_pdos);
  EXPECT_TRUE(g.modules[0].census);  // the default
  EXPECT_FALSE(g.modules[1].census);
}

TEST(Config, SurfaceWithListenerAndTwoSerialLinesLoads) {
  const SurfaceOptions s = load_surface(kConfigFixtures + "surface_serial.yaml");
  EXPECT_EQ(s.listen.to_string(), "127.0.0.1:7000");
  ASSERT_EQ(s.serial.size(), 2u);
  EXPECT_EQ(s.serial[0].device, "/dev/ttyS1");
  EXPECT_EQ(s.serial[0].baud, 115200u);  // the default
  EXPECT_FALSE(s.serial[0].hardware_flow_control);
  EXPECT_EQ(s.serial[1].device, "/dev/ttyUSB0");
  EXPECT_EQ(s.serial[1].baud, 921600u);
  EXPECT_TRUE(s.serial[1].hardware_flow_control);
  EXPECT_FALSE(s.conflate_pdos);
  EXPECT_EQ(s.session.conflate_after, std::chrono::milliseconds(0));  // 0 is valid: always
  EXPECT_EQ(s.session.keepalive, std::chrono::milliseconds(250));
  EXPECT_EQ(s.session.dead_after, std::chrono::milliseconds(1000));
  EXPECT_EQ(s.session.max_write_bytes, 512u);
  EXPECT_EQ(s.session.resend_buffer_bytes, SessionTuning{}.resend_buffer_bytes);
}

TEST(Config, SurfaceWithOnlySerialLinesHasNoListener) {
  const SurfaceOptions s =
      parse_surface("role: surface\nbus: vcan0\nbackbone:\n  serial:\n    - device: /dev/ttyS0\n" +
                        std::string(kPlainTail),
                    "s.yaml");
  EXPECT_TRUE(s.listen.host.empty());
  ASSERT_EQ(s.serial.size(), 1u);
}

// One fixture per mistake, each with exactly that one problem: the file, line and field it is
// reported at, and a piece of its message.
struct BadCase {
  const char* file;
  int line;
  const char* field;
  const char* text;
};

void expect_the_one_problem(const BadCase& c) {
  const std::string path = kConfigFixtures + c.file;
  const bool surface = std::string(c.file).rfind("surface", 0) == 0;
  const auto ps =
      problems_of([&] { surface ? (void)load_surface(path) : (void)load_gateway(path); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_EQ(ps[0].file, path);
  EXPECT_EQ(ps[0].line, c.line) << dump(ps);
  EXPECT_EQ(ps[0].field, c.field) << dump(ps);
  EXPECT_NE(ps[0].message.find(c.text), std::string::npos) << dump(ps);
}

std::string bad_case_name(const ::testing::TestParamInfo<BadCase>& param) {
  std::string name = param.param.file;
  return name.substr(0, name.find('.'));
}

class BadBackboneFile : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadBackboneFile, ReportsTheOneProblemWithFileLineAndField) {
  expect_the_one_problem(GetParam());
}

INSTANTIATE_TEST_SUITE_P(
    Config, BadBackboneFile,
    ::testing::Values(
        BadCase{"gateway_both_transports.yaml", 5, "backbone",
                "'connect' (line 4) and 'serial' (line 5) are both given"},
        BadCase{"gateway_no_transport.yaml", 2, "backbone",
                "needs 'connect: host:port' (TCP) or 'serial:' (a serial line): neither"},
        BadCase{"surface_no_transport.yaml", 3, "backbone",
                "needs 'listen: host:port' (TCP), 'serial:' lines, or both: neither"},
        BadCase{"gateway_bad_baud.yaml", 6, "backbone.serial.baud",
                "100000 is not a standard serial rate (e.g. 9600"},
        BadCase{"gateway_dead_after.yaml", 6, "backbone.dead_after_ms",
                "2000 must exceed keepalive_ms (2000)"},
        BadCase{"gateway_reliable_max_age.yaml", 6, "backbone.reliable_max_age_ms",
                "800 must exceed retransmit_ms (1000), or a frame lost once could never be "
                "resent"},
        BadCase{"surface_reliable_max_age_default.yaml", 6, "backbone.reliable_max_age_ms",
                "the default 4000 does not exceed retransmit_ms (5000)"},
        BadCase{"surface_duplicate_device.yaml", 8, "backbone.serial[2].device",
                "'/dev/ttyS1' is also the device of backbone.serial[0]"},
        BadCase{"gateway_serial_unknown_key.yaml", 6, "backbone.serial.parity", "unknown key"},
        BadCase{"surface_bad_flow_control.yaml", 7, "backbone.serial[0].flow_control",
                "'xonxoff' is not one of none, hardware"},
        BadCase{"gateway_conflate_not_bool.yaml", 8, "modules[0].conflate_pdos",
                "must be true or false"},
        BadCase{"gateway_census_not_bool.yaml", 8, "modules[0].census", "must be true or false"},
        BadCase{"surface_conflate_not_bool.yaml", 6, "backbone.conflate_pdos",
                "must be true or false"},
        BadCase{"gateway_conflate_after_too_long.yaml", 6, "backbone.conflate_after_ms",
                "60001 is out of range 0..60000"},
        BadCase{"surface_conflate_after_negative.yaml", 7, "backbone.conflate_after_ms",
                "-1 is out of range 0..60000"}),
    bad_case_name);

class BadPdopFile : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadPdopFile, ReportsTheOneProblemWithFileLineAndField) {
  expect_the_one_problem(GetParam());
}

INSTANTIATE_TEST_SUITE_P(
    Config, BadPdopFile,
    ::testing::Values(
        BadCase{"gateway_pdop_on_cia301.yaml", 8, "modules[0].pdop",
                "applies to pdop modules only (this module's profile is cia301)"},
        BadCase{"gateway_pdop_window_zero.yaml", 11, "modules[0].pdop.window",
                "0 is out of range 1..255"},
        BadCase{"gateway_pdop_packet_zero.yaml", 10, "modules[0].pdop.max_packet_bytes",
                "0 is out of range 1..524280"},
        BadCase{"gateway_pdop_packet_too_big.yaml", 10, "modules[0].pdop.max_packet_bytes",
                "600000 is out of range 1..524280"},
        BadCase{"gateway_pdop_unknown_key.yaml", 11, "modules[0].pdop.credit", "unknown key"},
        // Found by the segmenter's own validator, named as in the file.
        BadCase{"gateway_pdop_held_below_packet.yaml", 11, "modules[0].pdop.max_held_bytes",
                "4096 is outside max_packet_bytes (8192)..1073741824"},
        BadCase{"gateway_pdop_fragment_timeout_zero.yaml", 10,
                "modules[0].pdop.fragment_timeout_ms", "0 is out of range 1..10000"},
        // Issue 6: a pdop node cannot be presented above surface id 31, and the message says why.
        BadCase{"gateway_pdop_node_above_31.yaml", 9, "modules[0]",
                "surface node id 40 must be 1..31: a pdop bus keeps the node id in bits 4-0 "
                "(bits 6-5 are the PDO Packet toggle and continued bits)"},
        // One reliable message per packet: the resend buffer must hold the largest.
        BadCase{"gateway_pdop_packet_above_resend_buffer.yaml", 11,
                "modules[0].pdop.max_packet_bytes",
                "65536 does not fit in backbone.resend_buffer_bytes (65536) with its message"},
        BadCase{"surface_pdop_packet_above_resend_buffer.yaml", 8, "pdop.max_packet_bytes",
                "4096 does not fit in backbone.resend_buffer_bytes (4096) with its message"},
        BadCase{"surface_pdop_window_zero.yaml", 7, "pdop.window", "0 is out of range 1..255"},
        BadCase{"surface_pdop_unknown_key.yaml", 8, "pdop.ack_timeout_ms", "unknown key"}),
    bad_case_name);

TEST(Config, EveryPdopProblemOfAGatewayIsReportedAtOnce) {
  const std::string yaml =
      "role: gateway\n"                                     // 1
      "backbone:\n"                                         // 2
      "  connect: 127.0.0.1:7000\n"                         // 3
      "  auth: {mode: plain}\n"                             // 4
      "modules:\n"                                          // 5
      "  - id: 0\n"                                         // 6
      "    bus: vcan1\n"                                    // 7
      "    profile: pdop\n"                                 // 8
      "    nodes: {1: 1}\n"                                 // 9
      "    pdop:\n"                                         // 10
      "      window: 256\n"                                 // 11
      "      retries: 11\n"                                 // 12
      "      max_packet_bytes: 600000\n"                    // 13
      "      max_held_bytes: 2048\n"                        // 14
      "  - id: 1\n"                                         // 15
      "    bus: vcan2\n"                                    // 16
      "    profile: qd\n"                                   // 17
      "    nodes: {1: 20}\n"                                // 18
      "    pdop: {ack_timeout_ms: 0, reassemble: maybe}\n"  // 19
      "  - id: 2\n"                                         // 20
      "    bus: vcan3\n"                                    // 21
      "    profile: pdop\n"                                 // 22
      "    nodes: {1: 21}\n"                                // 23
      "    pdop:\n";                                        // 24
  const auto ps = problems_of([&] { parse_gateway(yaml, "p.yaml"); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 11, "modules[0].pdop.window", "256 is out of range 1..255")) << all;
  EXPECT_TRUE(has(ps, 12, "modules[0].pdop.retries", "11 is out of range 0..10")) << all;
  EXPECT_TRUE(has(ps, 13, "modules[0].pdop.max_packet_bytes", "out of range 1..524280")) << all;
  EXPECT_TRUE(has(ps, 19, "modules[1].pdop",
                  "applies to pdop modules only (this module's "
                  "profile is qd)"))
      << all;
  EXPECT_TRUE(has(ps, 19, "modules[1].pdop.ack_timeout_ms", "0 is out of range 1..10000")) << all;
  EXPECT_TRUE(has(ps, 19, "modules[1].pdop.reassemble", "must be true or false")) << all;
  EXPECT_TRUE(has(ps, 24, "modules[2].pdop", "must be a mapping")) << all;
  // Nothing else: max_held_bytes is not compared with a max_packet_bytes already refused.
  EXPECT_EQ(ps.size(), 7u) << all;
}

TEST(Config, EveryProblemOfABadSurfaceBackboneIsReportedAtOnce) {
  const std::string path = kConfigFixtures + "surface_bad.yaml";
  const auto ps = problems_of([&] { load_surface(path); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 7, "backbone.serial[0].baud", "115201 is not a standard serial rate")) << all;
  EXPECT_TRUE(has(ps, 8, "backbone.serial[0].flow_control", "'software'")) << all;
  EXPECT_TRUE(has(ps, 9, "backbone.serial[1].device", "also the device of backbone.serial[0]"))
      << all;
  EXPECT_TRUE(has(ps, 10, "backbone.serial[1].stop_bits", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 11, "backbone.serial[2].device", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 12, "backbone.conflate_pdos", "must be true or false")) << all;
  EXPECT_TRUE(has(ps, 13, "backbone.keepalive_ms", "out of range 10..600000")) << all;
  EXPECT_TRUE(has(ps, 15, "backbone.retransmit_ms", "out of range 10..600000")) << all;
  EXPECT_TRUE(has(ps, 16, "backbone.resend_buffer_messages", "out of range 1..1048576")) << all;
  EXPECT_TRUE(has(ps, 17, "backbone.resend_buffer_bytes", "out of range 1024..1073741824")) << all;
  EXPECT_TRUE(has(ps, 18, "backbone.max_write_bytes", "out of range 64..1048576")) << all;
  EXPECT_TRUE(has(ps, 19, "backbone.queue_reliable_frames", "out of range 1..4194304")) << all;
  EXPECT_TRUE(has(ps, 20, "backbone.queue_process_frames", "out of range 1..4194304")) << all;
  EXPECT_TRUE(has(ps, 21, "backbone.linger_ms", "unknown key")) << all;
  // Nothing else: dead_after_ms (line 14) is not compared with a keepalive_ms already refused.
  EXPECT_EQ(ps.size(), 14u) << all;
  for (const auto& p : ps) EXPECT_EQ(p.file, path);
}

TEST(Config, EveryProblemOfABadSerialGatewayIsReportedAtOnce) {
  const std::string path = kConfigFixtures + "gateway_serial_bad.yaml";
  const auto ps = problems_of([&] { load_gateway(path); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 4, "backbone.connect", "port 0")) << all;
  EXPECT_TRUE(has(ps, 5, "backbone", "both given")) << all;
  EXPECT_TRUE(has(ps, 6, "backbone.serial.device", "non-empty string")) << all;
  EXPECT_TRUE(has(ps, 7, "backbone.serial.baud", "'fast' is not an integer")) << all;
  EXPECT_TRUE(has(ps, 9, "backbone.serial.parity", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 11, "backbone.dead_after_ms", "900 must exceed keepalive_ms (1000)")) << all;
  EXPECT_TRUE(has(ps, 15, "modules[0].conflate_pdos", "must be true or false")) << all;
  EXPECT_EQ(ps.size(), 7u) << all;
}

TEST(Config, AnEmptySerialListIsNoTransport) {
  const auto ps = problems_of([] {
    parse_surface("role: surface\nbus: vcan0\nbackbone:\n  serial: []\n" + std::string(kPlainTail),
                  "n.yaml");
  });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 3, "backbone", "neither is given")) << dump(ps);
}

TEST(Config, KeepaliveAboveTheDefaultDeadAfterAsksForDeadAfter) {
  const auto ps = problems_of([] {
    parse_gateway(
        "role: gateway\nbackbone:\n  connect: 127.0.0.1:7000\n  keepalive_ms: 3000\n"
        "  auth: {mode: plain}\n"
        "modules: [{id: 1, bus: vcan1}]\n",
        "k.yaml");
  });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 4, "backbone.dead_after_ms", "the default 2000 does not exceed keepalive_ms"))
      << dump(ps);
}

TEST(Config, TcpFramingChoosesTheCrcFramingOrRefusesAnUnknownOne) {
  const char* base =
      "role: gateway\nbackbone:\n  connect: 127.0.0.1:7000\n  tcp_framing: {}\n"
      "  auth: {mode: plain}\n"
      "modules: [{id: 1, bus: vcan1}]\n";
  auto with = [&](const std::string& value) {
    std::string yaml = base;
    yaml.replace(yaml.find("{}"), 2, value);
    return yaml;
  };
  EXPECT_TRUE(parse_gateway(with("cobs-crc32c"), "t.yaml").session.tcp_crc_framing);
  EXPECT_FALSE(parse_gateway(with("length-prefix"), "t.yaml").session.tcp_crc_framing);
  const auto ps = problems_of([&] { parse_gateway(with("crc"), "t.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 4, "backbone.tcp_framing", "not one of length-prefix, cobs-crc32c"))
      << dump(ps);
}

TEST(Config, SerialOfTheWrongShapeSaysWhatEachRoleTakes) {
  const auto gateway = problems_of([] {
    parse_gateway(
        "role: gateway\nbackbone:\n  serial:\n    - device: /dev/ttyS1\n  auth: {mode: plain}\n"
        "modules: [{id: 1, bus: vcan1}]\n",
        "g.yaml");
  });
  EXPECT_TRUE(has(gateway, 4, "backbone.serial", "a gateway has one line")) << dump(gateway);
  EXPECT_EQ(gateway.size(), 1u) << dump(gateway);
  const auto surface = problems_of([] {
    parse_surface("role: surface\nbus: vcan0\nbackbone:\n  serial: {device: /dev/ttyS1}\n" +
                      std::string(kPlainTail),
                  "s.yaml");
  });
  EXPECT_TRUE(has(surface, 4, "backbone.serial", "must be a list of serial lines"))
      << dump(surface);
  EXPECT_EQ(surface.size(), 1u) << dump(surface);
  // "serial:" left without its lines, as when only that line of the example is uncommented.
  const auto empty = problems_of([] {
    parse_gateway(
        "role: gateway\nbackbone:\n  auth: {mode: plain}\n  serial:\nmodules: [{id: 1, bus: "
        "vcan1}]\n",
        "e.yaml");
  });
  EXPECT_TRUE(has(empty, 0, "backbone.serial", "must be a mapping")) << dump(empty);
  EXPECT_EQ(empty.size(), 1u) << dump(empty);
}

TEST(Config, BaudRatesOutsideTheTermiosSetAreRefused) {
  for (const char* baud : {"-9600", "0", "99999999999999999999999", "115200.0", "B115200"}) {
    const auto ps = problems_of([&] {
      parse_surface(std::string("role: surface\nbus: vcan0\nbackbone:\n  serial:\n"
                                "    - {device: /dev/ttyS1, baud: ") +
                        baud + "}\n" + kPlainTail,
                    "b.yaml");
    });
    EXPECT_TRUE(has(ps, 5, "backbone.serial[0].baud", "")) << baud << "\n" << dump(ps);
    EXPECT_EQ(ps.size(), 1u) << baud << "\n" << dump(ps);
  }
}

TEST(Config, EveryProblemOfABadFileIsReportedWithLineAndField) {
  auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_bad.yaml"); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 4, "backbone.connect", "must be host:port")) << all;
  EXPECT_TRUE(has(ps, 6, "backbone.reconnect_max_ms", "reconnect_min_ms")) << all;
  EXPECT_TRUE(has(ps, 10, "modules[1].id", "no default node map")) << all;
  EXPECT_TRUE(has(ps, 11, "modules[1].bus", "used by two modules")) << all;
  EXPECT_TRUE(has(ps, 14, "modules[2].nodes.2", "out of range 1..127")) << all;
  EXPECT_TRUE(has(ps, 15, "modules[3].id", "missing")) << all;
  EXPECT_TRUE(has(ps, 16, "modules[3].speed", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 18, "log.level", "'loud'")) << all;
  EXPECT_EQ(ps.size(), 8u) << all;
  EXPECT_NE(std::string(ConfigError(ps).what()).find("gateway_bad.yaml:18: log.level"),
            std::string::npos);
}

TEST(Config, OverlappingSurfaceIdsNameBothOwners) {
  auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_overlap.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_EQ(ps[0].line, 10);
  EXPECT_NE(
      ps[0].message.find("module 4 node 6: surface node id 7 is already owned by module 0 node 7"),
      std::string::npos)
      << ps[0].message;
}

TEST(Config, ModuleProfilesLoadWithCia301ByDefault) {
  const GatewayOptions g = load_gateway(kConfigFixtures + "gateway_profiles.yaml");
  ASSERT_EQ(g.modules.size(), 4u);
  EXPECT_EQ(g.modules[0].profile, bridge::IdProfile::qd);
  EXPECT_EQ(g.modules[1].profile, bridge::IdProfile::pdop);
  EXPECT_EQ(g.modules[2].profile, bridge::IdProfile::cia301);
  EXPECT_EQ(g.modules[3].profile, bridge::IdProfile::cia301);
  EXPECT_EQ(g.modules[1].heartbeat_lost_after, std::chrono::milliseconds(1500));
  EXPECT_FALSE(g.modules[0].heartbeat_lost_after);
  EXPECT_EQ(g.lss_module, 2u);
}

TEST(Config, LssModuleMustBeServedAndLostTimeInRange) {
  const auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_lss_bad.yaml"); });
  ASSERT_EQ(ps.size(), 2u) << dump(ps);
  EXPECT_TRUE(has(ps, 8, "modules[0].heartbeat_lost_ms", "10")) << dump(ps);
  EXPECT_TRUE(has(ps, 11, "lss_module", "module 3 is not one of this gateway's modules"))
      << dump(ps);
}

// A qd module's slot 1 (bits 6-5 = 01) is where a CiA 301 module's surface node 37 lives.
TEST(Config, OverlappingProfileImagesNameBothOwnersAndTheCobId) {
  const auto ps =
      problems_of([] { load_gateway(kConfigFixtures + "gateway_profile_overlap.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 12, "modules[1]",
                  "COB-ID 0x1A5: module 2 (cia301) local node 5 -> surface 37 TPDO1 collides "
                  "with module 1 (qd) local node 5 -> surface 5 TPDO2"))
      << dump(ps);
}

TEST(Config, ProfileProblemsAreReportedWithLineAndField) {
  const auto ps = problems_of([] { load_gateway(kConfigFixtures + "gateway_profile_bad.yaml"); });
  EXPECT_TRUE(has(ps, 9, "modules[0]", "module 0 node 2 (pdop): surface node id 40 must be 1..31"))
      << dump(ps);
  EXPECT_TRUE(has(ps, 12, "modules[1].profile", "a qd module needs surface node ids 1..31"))
      << dump(ps);
  EXPECT_TRUE(has(ps, 15, "modules[2].profile", "'canopen' is not one of cia301, pdop, qd"))
      << dump(ps);
  EXPECT_EQ(ps.size(), 3u) << dump(ps);
}

TEST(Config, AKeyGivenTwiceIsRefusedNotSilentlyOverwritten) {
  const auto ps = problems_of([] {
    parse_surface(
        "role: surface\nbus: vcan0\nbackbone: {listen: 127.0.0.1:7000, auth: {mode: "
        "plain}}\nbus: vcan1\n" +
            std::string(kOneGateway),
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
  EXPECT_EQ(missing[0].message, "cannot open the file: No such file or directory");
  auto empty = problems_of([] { parse_surface("role: surface\n", "z.yaml"); });
  EXPECT_EQ(empty.size(), 3u) << dump(empty);  // bus, backbone and gateways
  EXPECT_TRUE(has(empty, 0, "backbone", "'listen: host:port' (TCP), 'serial:' lines, or both"))
      << dump(empty);
  auto no_backbone = problems_of(
      [] { parse_gateway("role: gateway\nmodules: [{id: 1, bus: vcan1}]\n", "w.yaml"); });
  ASSERT_EQ(no_backbone.size(), 1u) << dump(no_backbone);
  EXPECT_TRUE(has(no_backbone, 0, "backbone", "'connect: host:port' (TCP) or 'serial:'"))
      << dump(no_backbone);
}

}  // namespace
}  // namespace canbridge::config
