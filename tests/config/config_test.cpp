#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <string>

#include "config/loader.hpp"
#include "tests/support/config_problems.hpp"

namespace canbridge::config {
namespace {

const std::string kConfigDir = CANBRIDGE_SOURCE_DIR "/config/";
const std::string kFixtures = CANBRIDGE_SOURCE_DIR "/tests/config/fixtures/";

using test::dump;
using test::has;
using test::problems_of;

// The samples give every session key at its default, documented beside it: this keeps what they
// say true when a default changes in options.hpp.
void expect_default_session(const SessionTuning& s) {
  const SessionTuning d;
  EXPECT_EQ(s.keepalive, d.keepalive);
  EXPECT_EQ(s.dead_after, d.dead_after);
  EXPECT_EQ(s.retransmit, d.retransmit);
  EXPECT_EQ(s.resend_buffer_messages, d.resend_buffer_messages);
  EXPECT_EQ(s.resend_buffer_bytes, d.resend_buffer_bytes);
  EXPECT_EQ(s.max_write_bytes, d.max_write_bytes);
  EXPECT_EQ(s.queue_reliable_frames, d.queue_reliable_frames);
  EXPECT_EQ(s.queue_process_frames, d.queue_process_frames);
}

// A sample with its commented-out serial example switched on ("  # serial:" and the "  #   "
// lines after it lose their "# "), without the lines starting with `drop` (if not empty): an
// operator following the comments gets a file that loads.
std::string with_serial_example(const std::string& path, const std::string& drop) {
  std::ifstream in(path);
  std::string text;
  bool block = false;
  for (std::string line; std::getline(in, line);) {
    block = line.rfind("  # serial:", 0) == 0 || (block && line.rfind("  #   ", 0) == 0);
    if (block) line.erase(2, 2);
    if (drop.empty() || line.rfind(drop, 0) != 0) text += line + "\n";
  }
  return text;
}

TEST(Config, SampleGatewayLoads) {
  const GatewayOptions g = load_gateway(kConfigDir + "gateway.yaml");
  EXPECT_EQ(g.connect.to_string(), "127.0.0.1:7000");
  ASSERT_EQ(g.modules.size(), 2u);
  EXPECT_EQ(g.modules[0].bus, "vcan1");
  EXPECT_EQ(g.modules[1].nodes.front(), (std::pair<std::uint8_t, std::uint8_t>{1, 65}));
  EXPECT_EQ(g.log.stats_interval, std::chrono::seconds(10));
  EXPECT_FALSE(g.serial.has_value());
  EXPECT_TRUE(g.modules[0].conflate_pdos);
  expect_default_session(g.session);
}

TEST(Config, SampleSurfaceLoads) {
  const SurfaceOptions s = load_surface(kConfigDir + "surface.yaml");
  EXPECT_EQ(s.bus, "vcan0");
  EXPECT_EQ(s.listen.port, 7000);
  EXPECT_TRUE(s.serial.empty());
  EXPECT_TRUE(s.conflate_pdos);
  expect_default_session(s.session);
}

TEST(Config, SampleSerialExamplesLoadWhenUncommented) {
  const std::string gateway_text = with_serial_example(kConfigDir + "gateway.yaml", "  connect:");
  ASSERT_NE(gateway_text.find("\n  serial:\n"), std::string::npos) << gateway_text;
  const GatewayOptions g = parse_gateway(gateway_text, "gateway.yaml (serial example)");
  ASSERT_TRUE(g.serial.has_value());
  EXPECT_EQ(g.serial->device, "/dev/ttyS1");
  EXPECT_EQ(g.serial->baud, 115200u);
  EXPECT_FALSE(g.serial->hardware_flow_control);

  const std::string surface_text = with_serial_example(kConfigDir + "surface.yaml", "");
  const SurfaceOptions s = parse_surface(surface_text, "surface.yaml (serial example)");
  EXPECT_EQ(s.listen.port, 7000);
  ASSERT_EQ(s.serial.size(), 2u) << surface_text;
  EXPECT_EQ(s.serial[1].device, "/dev/ttyUSB0");
  EXPECT_EQ(s.serial[1].baud, 460800u);
  EXPECT_TRUE(s.serial[1].hardware_flow_control);
}

TEST(Config, SerialGatewayLoads) {
  const GatewayOptions g = load_gateway(kFixtures + "gateway_serial.yaml");
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
  EXPECT_EQ(g.session.resend_buffer_messages, 256u);
  EXPECT_EQ(g.session.resend_buffer_bytes, 65536u);
  EXPECT_EQ(g.session.max_write_bytes, 512u);
  EXPECT_EQ(g.session.queue_reliable_frames, 4096u);
  EXPECT_EQ(g.session.queue_process_frames, 1024u);
  ASSERT_EQ(g.modules.size(), 2u);
  EXPECT_TRUE(g.modules[0].conflate_pdos);
  EXPECT_FALSE(g.modules[1].conflate_pdos);
}

TEST(Config, SurfaceWithListenerAndTwoSerialLinesLoads) {
  const SurfaceOptions s = load_surface(kFixtures + "surface_serial.yaml");
  EXPECT_EQ(s.listen.to_string(), "0.0.0.0:7000");
  ASSERT_EQ(s.serial.size(), 2u);
  EXPECT_EQ(s.serial[0].device, "/dev/ttyS1");
  EXPECT_EQ(s.serial[0].baud, 115200u);  // the default
  EXPECT_FALSE(s.serial[0].hardware_flow_control);
  EXPECT_EQ(s.serial[1].device, "/dev/ttyUSB0");
  EXPECT_EQ(s.serial[1].baud, 921600u);
  EXPECT_TRUE(s.serial[1].hardware_flow_control);
  EXPECT_FALSE(s.conflate_pdos);
  EXPECT_EQ(s.session.keepalive, std::chrono::milliseconds(250));
  EXPECT_EQ(s.session.dead_after, std::chrono::milliseconds(1000));
  EXPECT_EQ(s.session.max_write_bytes, 512u);
  EXPECT_EQ(s.session.resend_buffer_bytes, SessionTuning{}.resend_buffer_bytes);
}

TEST(Config, SurfaceWithOnlySerialLinesHasNoListener) {
  const SurfaceOptions s = parse_surface(
      "role: surface\nbus: vcan0\nbackbone:\n  serial:\n    - device: /dev/ttyS0\n", "s.yaml");
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

class BadBackboneFile : public ::testing::TestWithParam<BadCase> {};

TEST_P(BadBackboneFile, ReportsTheOneProblemWithFileLineAndField) {
  const BadCase& c = GetParam();
  const std::string path = kFixtures + c.file;
  const bool surface = std::string(c.file).rfind("surface", 0) == 0;
  const auto ps =
      problems_of([&] { surface ? (void)load_surface(path) : (void)load_gateway(path); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_EQ(ps[0].file, path);
  EXPECT_EQ(ps[0].line, c.line) << dump(ps);
  EXPECT_EQ(ps[0].field, c.field) << dump(ps);
  EXPECT_NE(ps[0].message.find(c.text), std::string::npos) << dump(ps);
}

INSTANTIATE_TEST_SUITE_P(
    Config, BadBackboneFile,
    ::testing::Values(
        BadCase{"gateway_both_transports.yaml", 4, "backbone",
                "'connect' (line 3) and 'serial' (line 4) are both given"},
        BadCase{"gateway_no_transport.yaml", 2, "backbone",
                "needs 'connect: host:port' (TCP) or 'serial:' (a serial line): neither"},
        BadCase{"surface_no_transport.yaml", 3, "backbone",
                "needs 'listen: host:port' (TCP), 'serial:' lines, or both: neither"},
        BadCase{"gateway_bad_baud.yaml", 5, "backbone.serial.baud",
                "100000 is not a standard serial rate (e.g. 9600"},
        BadCase{"gateway_dead_after.yaml", 5, "backbone.dead_after_ms",
                "2000 must exceed keepalive_ms (2000)"},
        BadCase{"surface_duplicate_device.yaml", 7, "backbone.serial[2].device",
                "'/dev/ttyS1' is also the device of backbone.serial[0]"},
        BadCase{"gateway_serial_unknown_key.yaml", 5, "backbone.serial.parity", "unknown key"},
        BadCase{"surface_bad_flow_control.yaml", 6, "backbone.serial[0].flow_control",
                "'xonxoff' is not one of none, hardware"},
        BadCase{"gateway_conflate_not_bool.yaml", 7, "modules[0].conflate_pdos",
                "must be true or false"},
        BadCase{"surface_conflate_not_bool.yaml", 5, "backbone.conflate_pdos",
                "must be true or false"}),
    [](const ::testing::TestParamInfo<BadCase>& param) {
      std::string name = param.param.file;
      name = name.substr(0, name.find('.'));
      return name;
    });

TEST(Config, EveryProblemOfABadSurfaceBackboneIsReportedAtOnce) {
  const std::string path = kFixtures + "surface_bad.yaml";
  const auto ps = problems_of([&] { load_surface(path); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 6, "backbone.serial[0].baud", "115201 is not a standard serial rate")) << all;
  EXPECT_TRUE(has(ps, 7, "backbone.serial[0].flow_control", "'software'")) << all;
  EXPECT_TRUE(has(ps, 8, "backbone.serial[1].device", "also the device of backbone.serial[0]"))
      << all;
  EXPECT_TRUE(has(ps, 9, "backbone.serial[1].stop_bits", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 10, "backbone.serial[2].device", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 11, "backbone.conflate_pdos", "must be true or false")) << all;
  EXPECT_TRUE(has(ps, 12, "backbone.keepalive_ms", "out of range 10..600000")) << all;
  EXPECT_TRUE(has(ps, 14, "backbone.retransmit_ms", "out of range 10..600000")) << all;
  EXPECT_TRUE(has(ps, 15, "backbone.resend_buffer_messages", "out of range 1..1048576")) << all;
  EXPECT_TRUE(has(ps, 16, "backbone.resend_buffer_bytes", "out of range 1024..1073741824")) << all;
  EXPECT_TRUE(has(ps, 17, "backbone.max_write_bytes", "out of range 64..1048576")) << all;
  EXPECT_TRUE(has(ps, 18, "backbone.queue_reliable_frames", "out of range 1..4194304")) << all;
  EXPECT_TRUE(has(ps, 19, "backbone.queue_process_frames", "out of range 1..4194304")) << all;
  EXPECT_TRUE(has(ps, 20, "backbone.linger_ms", "unknown key")) << all;
  // Nothing else: dead_after_ms (line 13) is not compared with a keepalive_ms already refused.
  EXPECT_EQ(ps.size(), 14u) << all;
  for (const auto& p : ps) EXPECT_EQ(p.file, path);
}

TEST(Config, EveryProblemOfABadSerialGatewayIsReportedAtOnce) {
  const std::string path = kFixtures + "gateway_serial_bad.yaml";
  const auto ps = problems_of([&] { load_gateway(path); });
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 3, "backbone.connect", "port 0")) << all;
  EXPECT_TRUE(has(ps, 4, "backbone", "both given")) << all;
  EXPECT_TRUE(has(ps, 5, "backbone.serial.device", "non-empty string")) << all;
  EXPECT_TRUE(has(ps, 6, "backbone.serial.baud", "'fast' is not an integer")) << all;
  EXPECT_TRUE(has(ps, 8, "backbone.serial.parity", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 10, "backbone.dead_after_ms", "900 must exceed keepalive_ms (1000)")) << all;
  EXPECT_TRUE(has(ps, 14, "modules[0].conflate_pdos", "must be true or false")) << all;
  EXPECT_EQ(ps.size(), 7u) << all;
}

TEST(Config, AnEmptySerialListIsNoTransport) {
  const auto ps = problems_of(
      [] { parse_surface("role: surface\nbus: vcan0\nbackbone:\n  serial: []\n", "n.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 3, "backbone", "neither is given")) << dump(ps);
}

TEST(Config, KeepaliveAboveTheDefaultDeadAfterAsksForDeadAfter) {
  const auto ps = problems_of([] {
    parse_gateway(
        "role: gateway\nbackbone:\n  connect: 127.0.0.1:7000\n  keepalive_ms: 3000\n"
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
        "role: gateway\nbackbone:\n  serial:\n    - device: /dev/ttyS1\n"
        "modules: [{id: 1, bus: vcan1}]\n",
        "g.yaml");
  });
  EXPECT_TRUE(has(gateway, 4, "backbone.serial", "a gateway has one line")) << dump(gateway);
  EXPECT_EQ(gateway.size(), 1u) << dump(gateway);
  const auto surface = problems_of([] {
    parse_surface("role: surface\nbus: vcan0\nbackbone:\n  serial: {device: /dev/ttyS1}\n",
                  "s.yaml");
  });
  EXPECT_TRUE(has(surface, 4, "backbone.serial", "must be a list of serial lines"))
      << dump(surface);
  EXPECT_EQ(surface.size(), 1u) << dump(surface);
  // "serial:" left without its lines, as when only that line of the example is uncommented.
  const auto empty = problems_of([] {
    parse_gateway("role: gateway\nbackbone:\n  serial:\nmodules: [{id: 1, bus: vcan1}]\n",
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
                        baud + "}\n",
                    "b.yaml");
    });
    EXPECT_TRUE(has(ps, 5, "backbone.serial[0].baud", "")) << baud << "\n" << dump(ps);
    EXPECT_EQ(ps.size(), 1u) << baud << "\n" << dump(ps);
  }
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

TEST(Config, ModuleProfilesLoadWithCia301ByDefault) {
  const GatewayOptions g = load_gateway(kFixtures + "gateway_profiles.yaml");
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
  const auto ps = problems_of([] { load_gateway(kFixtures + "gateway_lss_bad.yaml"); });
  ASSERT_EQ(ps.size(), 2u) << dump(ps);
  EXPECT_TRUE(has(ps, 7, "modules[0].heartbeat_lost_ms", "10")) << dump(ps);
  EXPECT_TRUE(has(ps, 10, "lss_module", "module 3 is not one of this gateway's modules"))
      << dump(ps);
}

// A qd module's slot 1 (bits 6-5 = 01) is where a CiA 301 module's surface node 37 lives.
TEST(Config, OverlappingProfileImagesNameBothOwnersAndTheCobId) {
  const auto ps = problems_of([] { load_gateway(kFixtures + "gateway_profile_overlap.yaml"); });
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 11, "modules[1]",
                  "COB-ID 0x1A5: module 2 (cia301) local node 5 -> surface 37 TPDO1 collides "
                  "with module 1 (qd) local node 5 -> surface 5 TPDO2"))
      << dump(ps);
}

TEST(Config, ProfileProblemsAreReportedWithLineAndField) {
  const auto ps = problems_of([] { load_gateway(kFixtures + "gateway_profile_bad.yaml"); });
  EXPECT_TRUE(has(ps, 8, "modules[0]", "module 0 node 2 (pdop): surface node id 40 must be 1..31"))
      << dump(ps);
  EXPECT_TRUE(has(ps, 11, "modules[1].profile", "a qd module needs surface node ids 1..31"))
      << dump(ps);
  EXPECT_TRUE(has(ps, 14, "modules[2].profile", "'canopen' is not one of cia301, pdop, qd"))
      << dump(ps);
  EXPECT_EQ(ps.size(), 3u) << dump(ps);
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
