#include "sim/rig_file.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <sstream>

#include "tests/support/config_problems.hpp"

namespace canbridge::sim {
namespace {

using config::ConfigError;
using config::ConfigProblem;
using Bytes = std::vector<std::uint8_t>;

const std::string kRigs = CANBRIDGE_SOURCE_DIR "/config/rigs/";
const std::string kFixtures = CANBRIDGE_SOURCE_DIR "/tests/sim/fixtures/";

using test::dump;
using test::has;
using test::problems_of;

std::vector<ConfigProblem> problems_of_text(const std::string& yaml) {
  return problems_of([&] { parse_rig(yaml, "t.yaml"); });
}

// A rig of one bus `b` whose only node has `keys` (one per line, unindented). The node's first
// key is on line 4.
std::string one_node(const std::string& keys) {
  std::string s = "buses:\n  - name: b\n    nodes:\n      - ";
  std::istringstream in(keys);
  std::string line;
  bool first = true;
  while (std::getline(in, line)) {
    if (!first) s += "        ";
    s += line + "\n";
    first = false;
  }
  return s;
}

// Exactly one problem, on `field`, whose message contains `text`.
void expect_only(const std::string& yaml, const std::string& field, const std::string& text) {
  const auto ps = problems_of_text(yaml);
  EXPECT_EQ(ps.size(), 1u) << yaml << dump(ps);
  EXPECT_TRUE(has(ps, 0, field, text)) << yaml << dump(ps);
}

void expect_ok(const std::string& yaml) {
  try {
    parse_rig(yaml, "t.yaml");
  } catch (const ConfigError& e) {
    ADD_FAILURE() << yaml << e.what();
  }
}

const NodeSpec* find_node(const RigSpec& rig, const std::string& name) {
  for (const auto& b : rig.buses) {
    for (const auto& n : b.nodes) {
      if (n.name == name) return &n;
    }
  }
  return nullptr;
}

const ObjectSpec* find_object(const NodeSpec& node, std::uint16_t index, std::uint8_t sub = 0) {
  for (const auto& o : node.objects) {
    if (o.index == index && o.sub == sub) return &o;
  }
  return nullptr;
}

// --- The reference rigs ---------------------------------------------------------------------

TEST(RigFile, ToolStringHasFiveModuleBusesWithFpgaSampleStreams) {
  const RigSpec rig = load_rig(kRigs + "tool_string.yaml");
  EXPECT_EQ(rig.name, "tool_string");
  ASSERT_EQ(rig.buses.size(), 5u);
  const char* names[] = {"communication", "power", "probe", "sample", "pump"};
  for (std::size_t i = 0; i < 5; ++i) {
    EXPECT_EQ(rig.buses[i].name, names[i]);
    EXPECT_EQ(rig.buses[i].interface, "vcan" + std::to_string(i + 1));  // vcan0: the surface
    // Every module has a CPU board (cia301, id 1) and ids that fit the gateway's default map.
    ASSERT_FALSE(rig.buses[i].nodes.empty());
    EXPECT_EQ(rig.buses[i].nodes[0].kind, NodeKind::cia301);
    EXPECT_EQ(rig.buses[i].nodes[0].node_id, 1);
    for (const auto& n : rig.buses[i].nodes) EXPECT_LE(n.node_id, 31) << n.name;
  }
  int counts[4] = {};
  for (const auto& b : rig.buses) {
    for (const auto& n : b.nodes) ++counts[static_cast<int>(n.kind)];
  }
  EXPECT_EQ(counts[static_cast<int>(NodeKind::microcanopen)], 2);
  EXPECT_EQ(counts[static_cast<int>(NodeKind::qd)], 0);
  EXPECT_EQ(counts[static_cast<int>(NodeKind::fpga)], 6);
  EXPECT_EQ(counts[static_cast<int>(NodeKind::cia301)], 5);

  // 256-byte samples as PDO Packets on the probe and sample buses, from fpga nodes.
  for (const char* name : {"probe-gauge", "fluid-analyzer"}) {
    const NodeSpec* n = find_node(rig, name);
    ASSERT_NE(n, nullptr) << name;
    EXPECT_EQ(n->kind, NodeKind::fpga);
    const auto sample = std::find_if(n->traffic.begin(), n->traffic.end(), [](const auto& t) {
      return t.kind == TrafficSpec::Kind::pdop_sample;
    });
    ASSERT_NE(sample, n->traffic.end()) << name;
    EXPECT_EQ(sample->bytes, 256u);
    EXPECT_EQ(sample->pdo, 2u);
  }
  EXPECT_EQ(rig.buses[2].nodes[1].name, "probe-gauge");
  const ObjectSpec* pressure = find_object(rig.buses[2].nodes[1], 0x6000, 1);
  ASSERT_NE(pressure, nullptr);
  EXPECT_EQ(pressure->type, DataType::unsigned32);
  EXPECT_EQ(pressure->access, Access::ro);
  EXPECT_EQ(rig.buses[3].nodes[1].name, "fluid-analyzer");

  const NodeSpec* monitor = find_node(rig, "rail-monitor");
  ASSERT_NE(monitor, nullptr);
  EXPECT_EQ(monitor->kind, NodeKind::microcanopen);
  EXPECT_TRUE(monitor->auto_start);
  EXPECT_EQ(monitor->heartbeat_ms, 2500);

  // The probe CPU's RPDO 1 listens to the gauge's TPDO 1.
  const NodeSpec* cpu = find_node(rig, "probe-cpu");
  ASSERT_NE(cpu, nullptr);
  ASSERT_FALSE(cpu->rpdos.empty());
  EXPECT_EQ(cpu->rpdos[0].cob_id, 0x185u);
}

TEST(RigFile, LabInstrumentHasQdNodesOneToSixOnOneBus) {
  const RigSpec rig = load_rig(kRigs + "lab_instrument.yaml");
  ASSERT_EQ(rig.buses.size(), 1u);
  EXPECT_EQ(rig.buses[0].name, "lab");
  EXPECT_EQ(rig.buses[0].interface, "vcan1");
  const auto& nodes = rig.buses[0].nodes;
  ASSERT_EQ(nodes.size(), 7u);
  for (int i = 0; i < 6; ++i) {
    EXPECT_EQ(nodes[i].kind, NodeKind::qd);
    EXPECT_EQ(nodes[i].node_id, i + 1);
  }
  EXPECT_EQ(nodes[6].kind, NodeKind::cia301);  // the third-party module
  EXPECT_EQ(nodes[6].node_id, 20);

  bool above_four = false;
  bool tpdo_34 = false;
  int subsystem_events = 0;
  for (const auto& n : nodes) {
    for (const auto& t : n.tpdos) {
      above_four = above_four || t.number > 4;
      tpdo_34 = tpdo_34 || t.number == 34;
    }
    for (const auto& t : n.traffic) {
      if (t.kind == TrafficSpec::Kind::subsystem_event) ++subsystem_events;
    }
  }
  EXPECT_TRUE(above_four);
  EXPECT_TRUE(tpdo_34);
  EXPECT_GE(subsystem_events, 6);

  EXPECT_EQ(nodes[0].device_type, 0x00010000u);
  EXPECT_EQ(nodes[0].sdo_block_size, 64);
  EXPECT_EQ(nodes[0].emcy.holdoff, std::chrono::milliseconds(100));
  EXPECT_TRUE(nodes[1].loader.wait_for_command);  // the magnet waits for the host
  EXPECT_FALSE(nodes[0].loader.wait_for_command);
}

TEST(RigFile, DemoHasOneNodeOfEachKindOnTwoVirtualBuses) {
  const RigSpec rig = load_rig(kRigs + "demo.yaml");
  ASSERT_EQ(rig.buses.size(), 2u);
  std::set<NodeKind> kinds;
  for (const auto& b : rig.buses) {
    EXPECT_TRUE(b.interface.empty()) << b.name;
    for (const auto& n : b.nodes) EXPECT_TRUE(kinds.insert(n.kind).second) << n.name;
  }
  EXPECT_EQ(kinds.size(), 4u);
}

// --- Every key, round trip ----------------------------------------------------------------------

TEST(RigFile, EveryKeyRoundTripsIntoTheSpec) {
  const RigSpec rig = load_rig(kFixtures + "rig_every_key.yaml");
  EXPECT_EQ(rig.name, "every_key");
  EXPECT_EQ(rig.description, "Every key of the schema.");
  ASSERT_EQ(rig.buses.size(), 2u);
  EXPECT_EQ(rig.buses[0].interface, "vcan7");
  EXPECT_EQ(rig.buses[1].interface, "");

  ASSERT_EQ(rig.buses[0].nodes.size(), 1u);
  const NodeSpec& n = rig.buses[0].nodes[0];
  EXPECT_EQ(n.name, "full");
  EXPECT_EQ(n.kind, NodeKind::cia301);
  EXPECT_EQ(n.node_id, 127);
  EXPECT_EQ(n.device_type, 0x00020192u);
  EXPECT_EQ(n.identity.vendor_id, 0xDEADBEEFu);
  EXPECT_EQ(n.identity.product_code, 42u);
  EXPECT_EQ(n.identity.revision, 0x00010002u);
  EXPECT_EQ(n.identity.serial, 4294967295u);
  EXPECT_EQ(n.heartbeat_ms, 250);
  EXPECT_TRUE(n.auto_start);
  EXPECT_EQ(n.sdo_timeout, std::chrono::milliseconds(750));
  EXPECT_EQ(n.sdo_block_size, 32);

  struct Expected {
    std::uint16_t index;
    std::uint8_t sub;
    DataType type;
    Access access;
    Bytes value;
  };
  const Expected expected[] = {
      {0x2000, 0, DataType::boolean, Access::ro, {1}},
      {0x2001, 0, DataType::integer8, Access::rw, {0x80}},
      {0x2002, 0, DataType::integer16, Access::rw, {0xFE, 0xFF}},
      {0x2003, 0, DataType::integer32, Access::rw, {0xF0, 0xFF, 0xFF, 0xFF}},
      {0x2004, 0, DataType::integer64, Access::rw, {0, 0, 0, 0, 0, 0, 0, 0x80}},
      {0x2005, 0, DataType::unsigned8, Access::wo, {0xFF}},
      {0x2006, 0, DataType::unsigned16, Access::rw, {0x34, 0x12}},
      {0x2007, 0, DataType::unsigned32, Access::constant, {0xFF, 0xFF, 0xFF, 0xFF}},
      {0x2008, 0, DataType::unsigned64, Access::rw, Bytes(8, 0xFF)},
      {0x2009, 0, DataType::real32, Access::rw, {0x00, 0x00, 0xC0, 0x3F}},        // 1.5f
      {0x200A, 0, DataType::real64, Access::rw, {0, 0, 0, 0, 0, 0, 0xD0, 0xBF}},  // -0.25
      {0x200B, 0, DataType::visible_string, Access::rw, {'h', 0xC3, 0xA9, 'l', 'l', 'o'}},
      {0x200C, 0, DataType::octet_string, Access::rw, {0x01, 0x02, 0xFF}},
      {0x200D, 0, DataType::domain, Access::rw, Bytes(16, 0)},
      {0x200E, 254, DataType::unsigned16, Access::rw, {0, 0}},
      {0x1008, 0, DataType::visible_string, Access::rw, {}},
  };
  ASSERT_EQ(n.objects.size(), std::size(expected));
  for (std::size_t i = 0; i < std::size(expected); ++i) {
    const auto& e = expected[i];
    const auto& o = n.objects[i];
    EXPECT_EQ(o.index, e.index) << i;
    EXPECT_EQ(o.sub, e.sub) << i;
    EXPECT_EQ(o.type, e.type) << i;
    EXPECT_EQ(o.access, e.access) << i;
    EXPECT_EQ(o.value, e.value) << i;
  }

  ASSERT_EQ(n.tpdos.size(), 1u);
  const PdoSpec& t = n.tpdos[0];
  EXPECT_EQ(t.number, 1u);
  EXPECT_EQ(t.cob_id, 0x1A0u);
  EXPECT_FALSE(t.enabled);
  EXPECT_EQ(t.transmission_type, 1);
  EXPECT_EQ(t.inhibit_100us, 10);
  EXPECT_EQ(t.event_timer_ms, 20);
  ASSERT_EQ(t.mapping.size(), 4u);
  EXPECT_EQ(t.mapping[0].index, 0x2006);
  EXPECT_EQ(t.mapping[0].bits, 16);
  EXPECT_EQ(t.mapping[1].index, 0x2003);  // {index, sub, bits}: a part of the object
  EXPECT_EQ(t.mapping[1].bits, 8);
  EXPECT_EQ(t.mapping[2].index, 0x1001);  // no bits: the whole object
  EXPECT_EQ(t.mapping[2].bits, 8);
  EXPECT_EQ(t.mapping[3].index, 0x2009);
  EXPECT_EQ(t.mapping[3].bits, 32);

  ASSERT_EQ(n.rpdos.size(), 1u);
  EXPECT_EQ(n.rpdos[0].number, 4u);
  EXPECT_EQ(n.rpdos[0].cob_id, 0x181u);
  EXPECT_TRUE(n.rpdos[0].enabled);
  EXPECT_EQ(n.rpdos[0].transmission_type, 254);
  ASSERT_EQ(n.rpdos[0].mapping.size(), 1u);
  EXPECT_EQ(n.rpdos[0].mapping[0].bits, 8);

  ASSERT_EQ(n.traffic.size(), 1u);
  EXPECT_EQ(n.traffic[0].kind, TrafficSpec::Kind::counter);
  EXPECT_EQ(n.traffic[0].period, std::chrono::milliseconds(10));
  EXPECT_EQ(n.traffic[0].index, 0x2006);
  EXPECT_EQ(n.traffic[0].sub, 0);
  EXPECT_EQ(n.traffic[0].step, -3);

  ASSERT_EQ(rig.buses[1].nodes.size(), 3u);
  const NodeSpec& f = rig.buses[1].nodes[0];
  EXPECT_EQ(f.kind, NodeKind::fpga);
  EXPECT_EQ(f.pdop.max_packet_bytes, 2048u);
  EXPECT_EQ(f.pdop.fragment_timeout, std::chrono::milliseconds(50));
  EXPECT_EQ(f.pdop.window, 8);
  EXPECT_EQ(f.emcy.inhibit_100us, 20);
  ASSERT_EQ(f.tpdos.size(), 1u);
  EXPECT_FALSE(f.tpdos[0].cob_id.has_value());
  ASSERT_EQ(f.traffic.size(), 1u);
  EXPECT_EQ(f.traffic[0].kind, TrafficSpec::Kind::pdop_sample);
  EXPECT_EQ(f.traffic[0].pdo, 3u);
  EXPECT_EQ(f.traffic[0].bytes, 2048u);
  EXPECT_EQ(f.heartbeat_ms, 1000);  // NodeSpec's default

  const NodeSpec& q = rig.buses[1].nodes[1];
  EXPECT_EQ(q.kind, NodeKind::qd);
  EXPECT_EQ(q.emcy.inhibit_100us, 5);
  EXPECT_EQ(q.emcy.holdoff, std::chrono::milliseconds(300));
  EXPECT_FALSE(q.loader.application_valid);
  EXPECT_TRUE(q.loader.wait_for_command);
  ASSERT_EQ(q.tpdos.size(), 1u);
  EXPECT_EQ(q.tpdos[0].number, 34u);
  EXPECT_TRUE(q.tpdos[0].mapping.empty());
  ASSERT_EQ(q.traffic.size(), 1u);
  EXPECT_EQ(q.traffic[0].kind, TrafficSpec::Kind::subsystem_event);
  EXPECT_EQ(q.traffic[0].subsystem, 11u);

  const NodeSpec& m = rig.buses[1].nodes[2];
  EXPECT_EQ(m.kind, NodeKind::microcanopen);
  EXPECT_EQ(m.name, "");
  EXPECT_TRUE(m.auto_start);  // seeds/002: no NMT master, so the default is to start
  EXPECT_FALSE(f.auto_start);
}

// --- A bad file: every problem, not just the first --------------------------------------------

TEST(RigFile, EveryProblemOfABadFileIsReportedWithLineAndField) {
  const auto ps = problems_of([] { load_rig(kFixtures + "rig_many_problems.yaml"); });
  const std::string all = dump(ps);
  const std::string a = "buses[0].nodes[0].";
  const std::string d = "buses[0].nodes[3].";
  EXPECT_TRUE(has(ps, 3, "colour", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 10, a + "node_id", "out of range 1..31")) << all;
  EXPECT_TRUE(has(ps, 11, a + "heartbeat_ms", "out of range 0..65535")) << all;
  EXPECT_TRUE(has(ps, 12, a + "sdo", "expedited SDO only")) << all;
  EXPECT_TRUE(has(ps, 14, a + "objects[0].value", "does not fit unsigned8")) << all;
  EXPECT_TRUE(has(ps, 15, a + "objects[1].index", "1017h comes from heartbeat_ms")) << all;
  EXPECT_TRUE(has(ps, 16, a + "objects[2].type", "'float' is not a data type")) << all;
  EXPECT_TRUE(has(ps, 17, a + "objects[3].access", "'rx' is not ro, wo, rw or const")) << all;
  EXPECT_TRUE(has(ps, 18, a + "objects[4].value", "negative values are only for integer")) << all;
  EXPECT_TRUE(has(ps, 20, a + "tpdos[0].number", "out of range 1..4")) << all;
  EXPECT_TRUE(has(ps, 21, a + "tpdos[1].cob_id", "fpga PDOs are fixed")) << all;
  EXPECT_TRUE(has(ps, 22, a + "tpdos[2].map[0]", "7000:00 is not an object")) << all;
  EXPECT_TRUE(has(ps, 24, a + "traffic[0].kind", "subsystem_event is for qd")) << all;
  EXPECT_TRUE(has(ps, 25, a + "traffic[1].period_ms", "out of range 1..")) << all;
  EXPECT_TRUE(has(ps, 25, a + "traffic[1].pdo", "TPDO 3 is not in this node's tpdos")) << all;
  EXPECT_TRUE(has(ps, 27, "buses[0].nodes[1].kind", "'quantum' is not a node kind")) << all;
  EXPECT_TRUE(has(ps, 29, "buses[0].nodes[2].node_id", "missing")) << all;
  EXPECT_TRUE(has(ps, 33, d + "node_id", "node id 3 is already used on this bus by node 3 'b'"))
      << all;
  EXPECT_TRUE(has(ps, 35, d + "tpdos[0].number", "out of range 1..34")) << all;
  EXPECT_TRUE(has(ps, 37, d + "tpdos[2].number", "TPDO 1 is already defined at line 36")) << all;
  EXPECT_TRUE(has(ps, 39, d + "traffic[0].kind", "'wave' is not a traffic kind")) << all;
  EXPECT_TRUE(has(ps, 40, d + "traffic[1].object", "6000:00 is not in this node's objects")) << all;
  EXPECT_TRUE(has(ps, 41, "buses[1].name", "bus 'one' is already defined at line 5")) << all;
  EXPECT_TRUE(has(ps, 42, "buses[1].interface", "'vcan1' is already used")) << all;
  EXPECT_EQ(ps.size(), 24u) << all;
  for (const auto& p : ps) EXPECT_EQ(p.file, kFixtures + "rig_many_problems.yaml");
  EXPECT_NE(std::string(ConfigError(ps).what())
                .find("rig_many_problems.yaml:10: buses[0].nodes[0].node_id"),
            std::string::npos);
}

TEST(RigFile, SyntaxErrorNonMappingAndMissingFile) {
  auto syntax = problems_of_text("buses:\n  - name: [unclosed\n");
  ASSERT_EQ(syntax.size(), 1u);
  EXPECT_NE(syntax[0].message.find("YAML syntax error"), std::string::npos);
  EXPECT_GT(syntax[0].line, 0);

  auto list = problems_of_text("- a\n- b\n");
  ASSERT_EQ(list.size(), 1u);
  EXPECT_NE(list[0].message.find("must be a YAML mapping"), std::string::npos);

  auto missing = problems_of([] { load_rig(kFixtures + "no_such_rig.yaml"); });
  ASSERT_EQ(missing.size(), 1u);
  EXPECT_EQ(missing[0].file, kFixtures + "no_such_rig.yaml");
  EXPECT_NE(missing[0].message.find("cannot open"), std::string::npos);
}

// --- One test per rule ----------------------------------------------------------------------

TEST(RigFile, UnknownAndRepeatedKeysAreRefusedAtEveryLevel) {
  const auto ps = problems_of_text(R"(rig: r
extra: 1
buses:
  - name: b
    speed: 500
    nodes:
      - kind: qd
        node_id: 1
        nodeid: 2
        identity: {vendor: 1}
        sdo: {timeout: 1}
        objects:
          - {index: 0x2000, type: unsigned8, default: 1}
        tpdos:
          - {number: 1, cobid: 0x181, map: [{index: 0x2000, length: 8}]}
        emcy: {inhibit: 1}
        loader: {valid: true}
        traffic:
          - {kind: counter, period_ms: 1, object: "2000:00", bytes: 4}
      - kind: fpga
        node_id: 2
        pdop: {size: 1}
        heartbeat_ms: 100
        heartbeat_ms: 200
)");
  const std::string all = dump(ps);
  const std::string n = "buses[0].nodes[0].";
  EXPECT_TRUE(has(ps, 2, "extra", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 5, "buses[0].speed", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 9, n + "nodeid", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 10, n + "identity.vendor", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 11, n + "sdo.timeout", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 13, n + "objects[0].default", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 15, n + "tpdos[0].cobid", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 15, n + "tpdos[0].map[0].length", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 16, n + "emcy.inhibit", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 17, n + "loader.valid", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 19, n + "traffic[0].bytes", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 22, "buses[0].nodes[1].pdop.size", "unknown key")) << all;
  EXPECT_TRUE(has(ps, 24, "buses[0].nodes[1].heartbeat_ms", "given twice (first at line 23)"))
      << all;
  EXPECT_EQ(ps.size(), 13u) << all;
}

TEST(RigFile, RequiredKeysAreReportedWhereTheirMappingStarts) {
  expect_only("rig: r\n", "buses", "missing (required)");
  expect_only("buses: []\n", "buses", "non-empty list");
  const auto ps = problems_of_text(R"(buses:
  - nodes:
      - name: x
        objects:
          - {sub: 1}
        tpdos:
          - {map: []}
        traffic:
          - {object: "2000:00"}
)");
  const std::string all = dump(ps);
  const std::string n = "buses[0].nodes[0].";
  EXPECT_TRUE(has(ps, 2, "buses[0].name", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 3, n + "kind", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 3, n + "node_id", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 5, n + "objects[0].index", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 5, n + "objects[0].type", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 7, n + "tpdos[0].number", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 9, n + "traffic[0].kind", "missing (required)")) << all;
  EXPECT_TRUE(has(ps, 9, n + "traffic[0].period_ms", "missing (required)")) << all;
  EXPECT_EQ(ps.size(), 8u) << all;
}

TEST(RigFile, UnknownKindTypeAccessAndTrafficKindAreNamed) {
  expect_only(one_node("kind: canopen\nnode_id: 1"), "buses[0].nodes[0].kind",
              "'canopen' is not a node kind: microcanopen, qd, fpga or cia301");
  expect_only(one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x2000, type: uint8}]"),
              "buses[0].nodes[0].objects[0].type", "'uint8' is not a data type");
  expect_only(
      one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x2000, type: unsigned8, access: "
               "read}]"),
      "buses[0].nodes[0].objects[0].access", "'read' is not ro, wo, rw or const");
  expect_only(one_node("kind: cia301\nnode_id: 1\ntraffic: [{kind: ramp, period_ms: 5}]"),
              "buses[0].nodes[0].traffic[0].kind", "'ramp' is not a traffic kind");
}

TEST(RigFile, NodeIdRangeDependsOnKind) {
  expect_ok(one_node("kind: cia301\nnode_id: 127"));
  expect_ok(one_node("kind: microcanopen\nnode_id: 0x7F"));
  expect_ok(one_node("kind: qd\nnode_id: 31"));
  expect_ok(one_node("kind: fpga\nnode_id: 1"));
  expect_only(one_node("kind: cia301\nnode_id: 128"), "buses[0].nodes[0].node_id",
              "out of range 1..127");
  expect_only(one_node("kind: microcanopen\nnode_id: 0"), "buses[0].nodes[0].node_id",
              "out of range 1..127");
  expect_only(one_node("kind: qd\nnode_id: 32"), "buses[0].nodes[0].node_id",
              "qd nodes use ids 1..31");
  expect_only(one_node("kind: fpga\nnode_id: 0"), "buses[0].nodes[0].node_id",
              "fpga nodes use ids 1..31");
  expect_only(one_node("kind: fpga\nnode_id: five"), "buses[0].nodes[0].node_id",
              "'five' is not an integer");
}

TEST(RigFile, NodeIdsAreUniquePerBusNotPerRig) {
  const auto ps = problems_of_text(R"(buses:
  - name: a
    nodes:
      - {name: x, kind: cia301, node_id: 4}
      - {name: y, kind: microcanopen, node_id: 4}
  - name: b
    nodes:
      - {name: z, kind: cia301, node_id: 4}
)");
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(has(ps, 5, "buses[0].nodes[1].node_id",
                  "node id 4 is already used on this bus by cia301 node 4 'x' (line 4)"))
      << dump(ps);
}

TEST(RigFile, HighIdsCollideWithTheIdentifiersQdAndFpgaNodesBorrow) {
  const std::string bus = "buses:\n  - name: a\n    nodes:\n      - {kind: ";
  // fpga 5's PDO Packets use the identifiers of nodes 37, 69 and 101.
  expect_only(bus + "fpga, node_id: 5}\n      - {kind: cia301, node_id: 37}\n",
              "buses[0].nodes[1].node_id", "collides with fpga node 5");
  // qd 3 owns the PDO identifiers of nodes 35, 67 and 99.
  expect_only(bus + "qd, node_id: 3}\n      - {kind: microcanopen, node_id: 99}\n",
              "buses[0].nodes[1].node_id", "collides with qd node 3");
  expect_ok(bus + "qd, node_id: 3}\n      - {kind: cia301, node_id: 36}\n");
  expect_ok(bus + "cia301, node_id: 3}\n      - {kind: cia301, node_id: 35}\n");
}

TEST(RigFile, BusNamesAndInterfacesAreUnique) {
  const auto ps = problems_of_text(R"(buses:
  - {name: a, interface: vcan1}
  - {name: b, interface: vcan1}
  - {name: a}
  - {name: c, interface: a_very_long_ifname}
)");
  const std::string all = dump(ps);
  EXPECT_TRUE(has(ps, 3, "buses[1].interface", "already used by the bus at line 2")) << all;
  EXPECT_TRUE(has(ps, 4, "buses[2].name", "bus 'a' is already defined at line 2")) << all;
  EXPECT_TRUE(has(ps, 5, "buses[3].interface", "at most 15 characters")) << all;
  EXPECT_EQ(ps.size(), 3u) << all;
}

TEST(RigFile, ValuesMustFitTheirType) {
  struct Case {
    const char* object;   // flow mapping without braces
    const char* problem;  // nullptr: accepted
  };
  const Case cases[] = {
      {"type: unsigned8, value: 255", nullptr},
      {"type: unsigned8, value: 256", "256 does not fit unsigned8 (0..255)"},
      {"type: unsigned16, value: 0x10000", "does not fit unsigned16 (0..0xFFFF)"},
      {"type: unsigned64, value: 18446744073709551615", nullptr},
      {"type: unsigned64, value: 18446744073709551616", "does not fit unsigned64"},
      {"type: unsigned32, value: -1", "negative values are only for integer types"},
      {"type: integer8, value: -128", nullptr},
      {"type: integer8, value: -129", "does not fit integer8 (-128..127)"},
      {"type: integer16, value: 0x8000", "does not fit integer16"},
      {"type: integer64, value: -9223372036854775809", "does not fit integer64"},
      {"type: integer32, value: 1.5", "'1.5' is not an integer"},
      {"type: boolean, value: 2", "is not a boolean"},
      {"type: boolean, value: 0", nullptr},
      {"type: real32, value: 3.5e38", "does not fit real32"},
      {"type: real64, value: 3.5e38", nullptr},
      {"type: real32, value: .inf", nullptr},
      {"type: real32, value: warm", "'warm' is not a number"},
      {"type: visible_string, value: [1, 2]", "must be a string"},
      {"type: octet_string, value: abc", "must be a list of byte values"},
      {"type: domain, value: [1, 256]", "out of range 0..255"},
      {"type: domain, value: [1], size: 2", "give value or size, not both"},
      {"type: unsigned8, size: 1", "only octet_string and domain objects take a size"},
      {"type: unsigned16, value: [1]", "must be a number for unsigned16"},
  };
  for (const auto& c : cases) {
    const std::string yaml = one_node(
        std::string("kind: cia301\nnode_id: 1\nobjects: [{index: 0x2000, ") + c.object + "}]");
    if (c.problem == nullptr) {
      expect_ok(yaml);
    } else {
      const auto ps = problems_of_text(yaml);
      ASSERT_EQ(ps.size(), 1u) << c.object << "\n" << dump(ps);
      EXPECT_EQ(ps[0].line, 6) << c.object;
      EXPECT_NE(ps[0].message.find(c.problem), std::string::npos)
          << c.object << ": " << ps[0].message;
    }
  }
}

TEST(RigFile, ObjectsTheNodeBuildsItselfAreRefused) {
  auto refused = [](const char* kind, const char* index, const char* why) {
    expect_only(one_node(std::string("kind: ") + kind + "\nnode_id: 1\nobjects: [{index: " + index +
                         ", type: unsigned8}]"),
                "buses[0].nodes[0].objects[0].index", why);
  };
  refused("cia301", "0x1000", "1000h comes from device_type");
  refused("cia301", "0x1001", "1001h (error register)");
  refused("cia301", "0x1015", "emcy.inhibit_100us");
  refused("cia301", "0x1017", "heartbeat_ms");
  refused("cia301", "0x1018", "identity");
  refused("cia301", "0x1400", "use tpdos/rpdos");
  refused("cia301", "0x1BFF", "use tpdos/rpdos");
  refused("cia301", "0x0007", "data type definitions");
  refused("qd", "0x1F51", "qd loader download object");
  refused("qd", "0x2F00", "event reset register");
  refused("fpga", "0x5F00", "received PDO Packets");
  expect_ok(one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x1C00, type: unsigned8}]"));
  expect_ok(one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x1F51, type: unsigned8}]"));
  expect_ok(one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x5F00, type: unsigned8}]"));
}

TEST(RigFile, AnObjectDefinedTwiceIsRefused) {
  const auto ps = problems_of_text(one_node(R"(kind: cia301
node_id: 1
objects:
  - {index: 0x2000, sub: 1, type: unsigned8}
  - {index: 0x2000, sub: 2, type: unsigned8}
  - {index: 0x2000, sub: 0x01, type: unsigned16})"));
  ASSERT_EQ(ps.size(), 1u) << dump(ps);
  EXPECT_TRUE(
      has(ps, 9, "buses[0].nodes[0].objects[2].index", "2000:01 is already defined at line 7"))
      << dump(ps);
}

TEST(RigFile, MicrocanopenHasOnlyNumericProcessVariables) {
  const std::string head = "kind: microcanopen\nnode_id: 1\nobjects: [{index: ";
  expect_ok(one_node(head + "0x2000, type: integer32}]"));
  expect_ok(one_node(head + "0x9FFF, type: real32}]"));
  expect_only(one_node(head + "0x1008, type: unsigned8}]"), "buses[0].nodes[0].objects[0].index",
              "give process objects 2000h-9FFFh");
  expect_only(one_node(head + "0xA000, type: unsigned8}]"), "buses[0].nodes[0].objects[0].index",
              "give process objects 2000h-9FFFh");
  expect_only(one_node(head + "0x2000, type: unsigned64}]"), "buses[0].nodes[0].objects[0].type",
              "a number of 1 to 4 bytes");
  expect_only(one_node(head + "0x2000, type: visible_string, value: ab}]"),
              "buses[0].nodes[0].objects[0].type", "a number of 1 to 4 bytes");
  // Without an NMT master a MicroCANopen node starts itself, unless told otherwise.
  EXPECT_TRUE(
      parse_rig(one_node("kind: microcanopen\nnode_id: 1"), "t").buses[0].nodes[0].auto_start);
  EXPECT_FALSE(parse_rig(one_node("kind: microcanopen\nnode_id: 1\nauto_start: false"), "t")
                   .buses[0]
                   .nodes[0]
                   .auto_start);
  EXPECT_FALSE(parse_rig(one_node("kind: cia301\nnode_id: 1"), "t").buses[0].nodes[0].auto_start);
}

TEST(RigFile, FpgaObjectsFitOneExpeditedSdo) {
  const std::string head = "kind: fpga\nnode_id: 1\nobjects: [{index: 0x2000, ";
  expect_ok(one_node(head + "type: unsigned32}]"));
  expect_ok(one_node(head + "type: visible_string, value: abcd}]"));
  expect_only(one_node(head + "type: real64}]"), "buses[0].nodes[0].objects[0].type",
              "expedited SDO only, at most 4 bytes");
  expect_only(one_node(head + "type: domain, size: 5}]"), "buses[0].nodes[0].objects[0].type",
              "expedited SDO only");
  // A complete device holds objects of any length.
  expect_ok(
      one_node("kind: cia301\nnode_id: 1\nobjects: [{index: 0x2000, type: domain, size: "
               "100000}]"));
}

TEST(RigFile, PdoNumbersDependOnKindAndAreUnique) {
  expect_ok(one_node("kind: qd\nnode_id: 1\ntpdos: [{number: 34}]\nrpdos: [{number: 4}]"));
  expect_only(one_node("kind: qd\nnode_id: 1\ntpdos: [{number: 35}]"),
              "buses[0].nodes[0].tpdos[0].number", "out of range 1..34");
  expect_only(one_node("kind: qd\nnode_id: 1\nrpdos: [{number: 5}]"),
              "buses[0].nodes[0].rpdos[0].number", "every kind has RPDOs 1..4");
  for (const char* kind : {"cia301", "microcanopen", "fpga"}) {
    expect_only(one_node(std::string("kind: ") + kind + "\nnode_id: 1\ntpdos: [{number: 5}]"),
                "buses[0].nodes[0].tpdos[0].number", "only qd nodes have 34");
  }
  expect_only(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 0}]"),
              "buses[0].nodes[0].tpdos[0].number", "out of range 1..4");
  expect_only(one_node("kind: cia301\nnode_id: 1\nrpdos: [{number: 2}, {number: 2}]"),
              "buses[0].nodes[0].rpdos[1].number", "RPDO 2 is already defined at line 6");
  // TPDO n and RPDO n are different PDOs.
  expect_ok(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 2}]\nrpdos: [{number: 2}]"));
  expect_only(one_node("kind: cia301\nnode_id: 1\nrpdos: [{number: 1, event_ms: 5}]"),
              "buses[0].nodes[0].rpdos[0].event_ms", "applies to TPDOs only");
}

TEST(RigFile, MappedObjectsMustExistFitAndBeAccessible) {
  const std::string node = R"(kind: cia301
node_id: 1
objects:
  - {index: 0x2000, type: unsigned32, access: ro}
  - {index: 0x2001, type: unsigned64, access: rw}
  - {index: 0x2002, type: unsigned16, access: wo}
  - {index: 0x2003, type: visible_string, value: abc}
)";
  const std::string m = "buses[0].nodes[0].tpdos[0].map";
  auto tpdo = [&](const std::string& map) {
    return one_node(node + "tpdos: [{number: 1, map: " + map + "}]");
  };
  expect_ok(tpdo(R"(["2000:00", "1001:00/8", "2003:00/24"])"));  // 64 bits
  expect_ok(tpdo(R"(["2000:00/16"])"));                          // part of an object
  expect_ok(tpdo(R"(["2001:00"])"));
  expect_ok(tpdo(R"([{index: 0x2000, bits: 8}])"));
  expect_only(tpdo(R"(["2005:00"])"), m + "[0]", "2005:00 is not an object of this node");
  expect_only(tpdo(R"(["1018:01/32"])"), m + "[0]", "1018:01 is not an object of this node");
  expect_only(tpdo(R"(["2001:00", "2000:00/8"])"), m, "72 bits mapped: a PDO carries at most 64");
  expect_only(tpdo(R"(["2000:00/12"])"), m + "[0]", "a multiple of 8, from 8 to 64");
  expect_only(tpdo(R"(["2000:00/40"])"), m + "[0]", "40 bits is more than 2000:00 holds (32");
  expect_only(tpdo(R"(["2003:00/32"])"), m + "[0]", "more than 2003:00 holds (24");
  expect_only(tpdo(R"(["2002:00"])"), m + "[0]", "write-only");
  expect_only(tpdo(R"(["2000-00/8"])"), m + "[0]", "must be index:sub/bits");
  expect_only(tpdo(R"(["2000:00/x"])"), m + "[0]", "must be a length in bits");
  const std::string r = "buses[0].nodes[0].rpdos[0].map[0]";
  expect_ok(one_node(node + R"(rpdos: [{number: 1, map: ["2002:00", "2001:00/32"]}])"));
  expect_only(one_node(node + R"(rpdos: [{number: 1, map: ["2000:00"]}])"), r, "read-only");
  expect_only(one_node(node + R"(rpdos: [{number: 1, map: ["1001:00"]}])"), r, "read-only");
}

TEST(RigFile, CobIdsAreFixedOnFpgaQdAndMicrocanopenTpdos) {
  const std::string f = "buses[0].nodes[0].tpdos[0].cob_id";
  expect_only(one_node("kind: fpga\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x181}]"), f,
              "fpga PDOs are fixed: 4 TPDOs and 4 RPDOs at the predefined COB-IDs");
  expect_only(one_node("kind: fpga\nnode_id: 1\nrpdos: [{number: 1, cob_id: 0x201}]"),
              "buses[0].nodes[0].rpdos[0].cob_id", "fpga PDOs are fixed");
  expect_only(one_node("kind: qd\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x181}]"), f,
              "qd PDOs have fixed COB-IDs from the extended connection set");
  expect_only(one_node("kind: microcanopen\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x181}]"), f,
              "only RPDO COB-IDs can be changed");
  expect_ok(one_node("kind: microcanopen\nnode_id: 1\nrpdos: [{number: 2, cob_id: 0x188}]"));
  expect_ok(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x3FF}]"));
  expect_only(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x800}]"), f,
              "out of range 0x0000..0x07FF");
  expect_only(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 1, cob_id: 0x581}]"), f,
              "restricted by CiA 301");
  expect_only(one_node("kind: cia301\nnode_id: 1\nrpdos: [{number: 1, cob_id: 0}]"),
              "buses[0].nodes[0].rpdos[0].cob_id", "restricted by CiA 301");
}

TEST(RigFile, AnExplicitTpdoCobIdHasOneTransmitterOnTheBus) {
  const std::string bus = "buses:\n  - name: a\n    nodes:\n";
  // cia301 node 9's TPDO 1 on 0x182 would collide with cia301 node 2's predefined TPDO 1.
  expect_only(bus + "      - {kind: cia301, node_id: 2, tpdos: [{number: 1}]}\n" +
                  "      - {kind: cia301, node_id: 9, tpdos: [{number: 1, cob_id: 0x182}]}\n",
              "buses[0].nodes[1].tpdos[0].cob_id",
              "0x182 is already transmitted by cia301 node 2 TPDO 1");
  // 0x1A5 is a fragment identifier of fpga node 5's TPDO 1 PDO Packets.
  expect_only(bus + "      - {kind: fpga, node_id: 5, tpdos: [{number: 1}]}\n" +
                  "      - {kind: cia301, node_id: 9, tpdos: [{number: 1, cob_id: 0x1A5}]}\n",
              "buses[0].nodes[1].tpdos[0].cob_id", "PDO Packet fragments");
  // 0x2C3 is qd node 3's TPDO 10.
  expect_only(bus + "      - {kind: qd, node_id: 3}\n" +
                  "      - {kind: cia301, node_id: 9, tpdos: [{number: 1, cob_id: 0x2C3}]}\n",
              "buses[0].nodes[1].tpdos[0].cob_id", "extended connection set");
  // ... but 0x203 is qd node 3's RPDO 1: another node may send to it.
  expect_ok(bus + "      - {kind: qd, node_id: 3}\n" +
            "      - {kind: cia301, node_id: 9, tpdos: [{number: 1, cob_id: 0x203}]}\n");
}

TEST(RigFile, TransmissionTypes) {
  const std::string f = "buses[0].nodes[0].tpdos[0].transmission";
  auto tpdo = [](const char* kind, const char* type) {
    return one_node(std::string("kind: ") + kind +
                    "\nnode_id: 1\ntpdos: [{number: 1, "
                    "transmission: " +
                    type + "}]");
  };
  expect_ok(tpdo("cia301", "0"));
  expect_ok(tpdo("cia301", "240"));
  expect_ok(tpdo("qd", "254"));
  expect_only(tpdo("cia301", "241"), f, "241..251 are reserved");
  expect_only(tpdo("cia301", "252"), f, "remote-request");
  expect_only(tpdo("cia301", "256"), f, "out of range 0..255");
  expect_only(tpdo("microcanopen", "1"), f, "microcanopen TPDOs are event-driven only");
  expect_ok(tpdo("microcanopen", "255"));
}

TEST(RigFile, CounterTrafficNeedsAnIntegerObjectOfTheNode) {
  const std::string node = R"(kind: cia301
node_id: 1
objects:
  - {index: 0x2000, type: unsigned8}
  - {index: 0x2001, type: real32}
  - {index: 0x2003, type: unsigned8, access: const}
traffic:
)";
  const std::string t = "buses[0].nodes[0].traffic[0].";
  expect_ok(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2000:00\", step: -1}"));
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2002:00\"}"),
              t + "object", "2002:00 is not in this node's objects");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"1001:00\"}"),
              t + "object", "1001:00 is not in this node's objects");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2001:00\"}"),
              t + "object", "real32: a counter needs an integer or unsigned object");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2003:00\"}"),
              t + "object", "2003:00 is const");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: 2000}"), t + "object",
              "must name an object as index:sub");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2000:00\", step: 0}"),
              t + "step", "never change");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 0, object: \"2000:00\"}"),
              t + "period_ms", "out of range 1..");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1}"), t + "object", "missing");
  expect_only(one_node(node + "  - {kind: counter, period_ms: 1, object: \"2000:00\", pdo: 1}"),
              t + "pdo", "unknown key");
}

TEST(RigFile, PdopSampleTrafficIsForFpgaTpdosWithinThePacketLimit) {
  const std::string node = R"(kind: fpga
node_id: 1
pdop: {max_packet_bytes: 512}
tpdos: [{number: 1}, {number: 2, enabled: false}]
traffic:
)";
  const std::string t = "buses[0].nodes[0].traffic[0].";
  expect_ok(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 1, bytes: 512}"));
  expect_ok(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 1}"));  // 256 bytes
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 1, bytes: 513}"),
              t + "bytes", "out of range 1..512 (pdop.max_packet_bytes)");
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 1, bytes: 0}"),
              t + "bytes", "out of range 1..512");
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 5}"), t + "pdo",
              "out of range 1..4");
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 3}"), t + "pdo",
              "TPDO 3 is not in this node's tpdos");
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10, pdo: 2}"), t + "pdo",
              "TPDO 2 is disabled");
  expect_only(one_node(node + "  - {kind: pdop_sample, period_ms: 10}"), t + "pdo", "missing");
  expect_only(
      one_node("kind: fpga\nnode_id: 1\npdop: {max_packet_bytes: 100}\ntpdos: [{number: 1}]\n"
               "traffic: [{kind: pdop_sample, period_ms: 10, pdo: 1}]"),
      t + "bytes", "the default of 256 bytes is more than pdop.max_packet_bytes");
  expect_only(one_node("kind: cia301\nnode_id: 1\ntpdos: [{number: 1}]\n"
                       "traffic: [{kind: pdop_sample, period_ms: 10, pdo: 1}]"),
              t + "kind", "pdop_sample is for fpga nodes");
}

TEST(RigFile, SubsystemEventTrafficIsForQdSubsystemsZeroToEleven) {
  const std::string t = "buses[0].nodes[0].traffic[0].";
  auto event = [](const char* kind, const char* subsystem) {
    return one_node(std::string("kind: ") + kind +
                    "\nnode_id: 1\ntraffic: [{kind: subsystem_event, period_ms: 100, "
                    "subsystem: " +
                    subsystem + "}]");
  };
  expect_ok(event("qd", "0"));
  expect_ok(event("qd", "11"));
  expect_only(event("qd", "12"), t + "subsystem", "out of range 0..11");
  expect_only(event("fpga", "1"), t + "kind", "subsystem_event is for qd nodes");
  expect_only(one_node("kind: qd\nnode_id: 1\ntraffic: [{kind: subsystem_event, period_ms: 9}]"),
              t + "subsystem", "missing");
}

TEST(RigFile, KindSpecificSections) {
  const std::string n = "buses[0].nodes[0].";
  expect_only(one_node("kind: fpga\nnode_id: 1\nsdo: {block_size: 4}"), n + "sdo",
              "fpga nodes serve expedited SDO only");
  expect_only(one_node("kind: microcanopen\nnode_id: 1\nsdo: {timeout_ms: 4}"), n + "sdo",
              "microcanopen nodes serve expedited SDO only");
  expect_ok(one_node("kind: qd\nnode_id: 1\nsdo: {timeout_ms: 4, block_size: 1}"));
  expect_only(one_node("kind: qd\nnode_id: 1\npdop: {window: 2}"), n + "pdop",
              "only fpga nodes speak PDO Packets");
  expect_only(one_node("kind: cia301\nnode_id: 1\nloader: {wait_for_command: true}"), n + "loader",
              "only qd nodes have the CANopen loader");
  expect_only(one_node("kind: fpga\nnode_id: 1\nemcy: {holdoff_ms: 10}"), n + "emcy.holdoff_ms",
              "only qd nodes send state-change EMCYs");
  expect_ok(one_node("kind: fpga\nnode_id: 1\nemcy: {inhibit_100us: 10}"));
  expect_only(one_node("kind: qd\nnode_id: 1\ndevice_type: 0x00010191"), n + "device_type",
              "profile number 0 in the low 16 bits");
  expect_ok(one_node("kind: qd\nnode_id: 1\ndevice_type: 0x00020000"));
  expect_ok(one_node("kind: cia301\nnode_id: 1\ndevice_type: 0x00010191"));
}

TEST(RigFile, NumericLimits) {
  const std::string n = "buses[0].nodes[0].";
  expect_ok(one_node("kind: cia301\nnode_id: 1\nheartbeat_ms: 0"));
  expect_ok(one_node("kind: cia301\nnode_id: 1\nheartbeat_ms: 65535"));
  expect_only(one_node("kind: cia301\nnode_id: 1\nheartbeat_ms: -1"), n + "heartbeat_ms",
              "out of range 0..65535");
  expect_only(one_node("kind: cia301\nnode_id: 1\nsdo: {block_size: 0}"), n + "sdo.block_size",
              "out of range 1..127");
  expect_only(one_node("kind: cia301\nnode_id: 1\nsdo: {block_size: 128}"), n + "sdo.block_size",
              "out of range 1..127");
  expect_only(one_node("kind: fpga\nnode_id: 1\npdop: {window: 0}"), n + "pdop.window",
              "out of range 1..255");
  expect_only(one_node("kind: fpga\nnode_id: 1\npdop: {window: 256}"), n + "pdop.window",
              "out of range 1..255");
  expect_only(one_node("kind: fpga\nnode_id: 1\npdop: {max_packet_bytes: 524281}"),
              n + "pdop.max_packet_bytes", "out of range 1..524280");
  expect_only(one_node("kind: cia301\nnode_id: 1\nidentity: {serial: 0x100000000}"),
              n + "identity.serial", "out of range 0x00000000..0xFFFFFFFF");
  expect_only(one_node("kind: cia301\nnode_id: 1\nauto_start: maybe"), n + "auto_start",
              "must be true or false");
}

TEST(RigFile, NodeKindNamesRoundTrip) {
  for (auto kind : {NodeKind::microcanopen, NodeKind::qd, NodeKind::fpga, NodeKind::cia301}) {
    EXPECT_EQ(parse_node_kind(to_string(kind)), kind);
  }
  EXPECT_FALSE(parse_node_kind("CiA301").has_value());
  EXPECT_STREQ(to_string(NodeKind::qd), "qd");
}

}  // namespace
}  // namespace canbridge::sim
