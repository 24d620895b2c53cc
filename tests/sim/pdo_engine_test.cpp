// Default connection sets (seeds/003 figure 4, CiA 301 predefined set) and the PDO engine, frame by
// frame with injected time.
#include "sim/pdo_engine.hpp"

#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <memory>
#include <utility>

#include "canopen/sdo_abort.hpp"
#include "sim/connection_set.hpp"

namespace canbridge::sim {
namespace {

using namespace std::chrono_literals;
using canopen::SdoAbort;
using Bytes = std::vector<std::uint8_t>;
using Frames = std::vector<can::Frame>;
using TimePoint = PdoEngine::TimePoint;

const TimePoint kEngineStart = TimePoint{} + 1000s;

// ---- connection set -------------------------------------------------------------------------

// seeds/003 figure 4, rows 1..34, as offsets from node N.
constexpr std::array<std::uint32_t, 34> kQdFigure = {
    0x180, 0x1A0, 0x1C0, 0x1E0, 0x220, 0x240, 0x260, 0x280, 0x2A0, 0x2C0, 0x2E0, 0x320,
    0x340, 0x360, 0x380, 0x3A0, 0x3C0, 0x3E0, 0x420, 0x440, 0x460, 0x480, 0x4A0, 0x4C0,
    0x4E0, 0x520, 0x540, 0x560, 0x5A0, 0x5C0, 0x5E0, 0x620, 0x640, 0x660};

TEST(ConnectionSet, QdTpdosFollowSeedFigureForNode1And31) {
  ASSERT_EQ(max_tpdos(NodeKind::qd), 34u);
  for (const canopen::NodeId node : {canopen::NodeId{1}, canopen::NodeId{31}}) {
    for (unsigned number = 1; number <= 34; ++number) {
      EXPECT_EQ(default_tpdo_cob_id(NodeKind::qd, node, number), kQdFigure[number - 1] + node)
          << "node " << int{node} << " TPDO " << number;
    }
  }
  // Node 31's last image is 0x660 + 31 = 0x67F, still an 11-bit id below the heartbeat range.
  EXPECT_EQ(default_tpdo_cob_id(NodeKind::qd, 31, 34), 0x67Fu);
}

TEST(ConnectionSet, QdRpdosAreThePredefinedOnes) {
  EXPECT_EQ(max_rpdos(NodeKind::qd), 4u);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::qd, 1, 1), 0x201u);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::qd, 1, 2), 0x301u);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::qd, 31, 3), 0x41Fu);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::qd, 31, 4), 0x51Fu);
}

TEST(ConnectionSet, OtherKindsUseThePredefinedSet) {
  for (const NodeKind kind : {NodeKind::cia301, NodeKind::microcanopen, NodeKind::fpga}) {
    EXPECT_EQ(max_tpdos(kind), 4u);
    EXPECT_EQ(max_rpdos(kind), 4u);
    EXPECT_EQ(default_tpdo_cob_id(kind, 127, 1), 0x1FFu);
    EXPECT_EQ(default_tpdo_cob_id(kind, 127, 2), 0x2FFu);
    EXPECT_EQ(default_tpdo_cob_id(kind, 127, 3), 0x3FFu);
    EXPECT_EQ(default_tpdo_cob_id(kind, 127, 4), 0x4FFu);
    EXPECT_EQ(default_rpdo_cob_id(kind, 127, 1), 0x27Fu);
    EXPECT_EQ(default_rpdo_cob_id(kind, 127, 2), 0x37Fu);
    EXPECT_EQ(default_rpdo_cob_id(kind, 127, 3), 0x47Fu);
    EXPECT_EQ(default_rpdo_cob_id(kind, 127, 4), 0x57Fu);
    EXPECT_EQ(default_tpdo_cob_id(kind, 127, 5), std::nullopt);
  }
}

TEST(ConnectionSet, OutOfRangeIsNullopt) {
  EXPECT_EQ(default_tpdo_cob_id(NodeKind::qd, 1, 0), std::nullopt);
  EXPECT_EQ(default_tpdo_cob_id(NodeKind::qd, 1, 35), std::nullopt);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::qd, 1, 5), std::nullopt);
  EXPECT_EQ(default_tpdo_cob_id(NodeKind::qd, 32, 1), std::nullopt);  // N+96 would pass 127
  EXPECT_EQ(default_tpdo_cob_id(NodeKind::cia301, 0, 1), std::nullopt);
  EXPECT_EQ(default_rpdo_cob_id(NodeKind::cia301, 128, 1), std::nullopt);
}

// ---- PDO engine -----------------------------------------------------------------------------

constexpr std::uint16_t kU8 = 0x6000;   // sub 1: UNSIGNED8 rw
constexpr std::uint16_t kU16 = 0x6001;  // sub 0: UNSIGNED16 rw
constexpr std::uint16_t kU32 = 0x6002;  // sub 0: UNSIGNED32 rw
constexpr std::uint16_t kWriteOnly = 0x6003;
constexpr std::uint16_t kReadOnly = 0x6004;

PdoSpec pdo(unsigned number, std::uint32_t cob_id, std::uint8_t type,
            std::vector<PdoMapEntry> mapping) {
  PdoSpec spec;
  spec.number = number;
  spec.cob_id = cob_id;
  spec.transmission_type = type;
  spec.mapping = std::move(mapping);
  return spec;
}

const std::vector<PdoMapEntry> kU16Mapping = {{kU16, 0, 16}};

Bytes u32(std::uint32_t value) {
  return le_bytes(value, 4);
}

class PdoEngineTest : public ::testing::Test {
 protected:
  PdoEngineTest() {
    od.add_unsigned(kU8, 1, Access::rw, 0x11, 1);
    od.add_unsigned(kU16, 0, Access::rw, 0x1234, 2);
    od.add_unsigned(kU32, 0, Access::rw, 0xA1B2C3D4, 4);
    od.add_unsigned(kWriteOnly, 0, Access::wo, 0, 1);
    od.add_unsigned(kReadOnly, 0, Access::ro, 0, 1);
  }

  // Installs the PDOs and wires the dictionary's guard and listener to the engine, as the node
  // does.
  void make(std::vector<PdoSpec> tpdos, std::vector<PdoSpec> rpdos = {},
            PdoEngine::InstallOptions options = {}) {
    PdoEngine::install(od, tpdos, rpdos, options);
    engine = std::make_unique<PdoEngine>(od, options);
    od.set_write_guard([this](const OdEntry& entry, std::span<const std::uint8_t> data) {
      return engine->check_write(entry, data);
    });
    od.set_write_listener([this](const OdEntry& entry) { engine->on_written(entry, now, out); });
  }

  // Device-side change of the mapped UNSIGNED16, then the poll the node does after it.
  void set_u16(std::uint16_t value) {
    od.set_unsigned(kU16, 0, value);
    engine->poll(now, out);
  }

  Frames take() { return std::exchange(out, {}); }

  ObjectDictionary od;
  std::unique_ptr<PdoEngine> engine;
  TimePoint now = kEngineStart;
  Frames out;
};

TEST_F(PdoEngineTest, InstallAddsCommunicationAndMappingObjects) {
  PdoSpec tpdo = pdo(2, 0x281, 254, {{kU8, 1, 8}, {kU16, 0, 16}});
  tpdo.inhibit_100us = 50;
  tpdo.event_timer_ms = 250;
  PdoSpec rpdo = pdo(1, 0x201, 255, {{kU32, 0, 32}});
  rpdo.enabled = false;
  make({tpdo}, {rpdo});

  ASSERT_NE(od.find(0x1801, 0), nullptr);
  EXPECT_EQ(od.find(0x1801, 0)->access, Access::constant);
  EXPECT_EQ(od.get_unsigned(0x1801, 0), 5u);
  EXPECT_EQ(od.get_unsigned(0x1801, 1), 0x281u);
  EXPECT_EQ(od.find(0x1801, 1)->access, Access::rw);
  EXPECT_EQ(od.find(0x1801, 1)->type, DataType::unsigned32);
  EXPECT_EQ(od.get_unsigned(0x1801, 2), 254u);
  EXPECT_EQ(od.get_unsigned(0x1801, 3), 50u);
  EXPECT_EQ(od.find(0x1801, 3)->type, DataType::unsigned16);
  EXPECT_EQ(od.read(0x1801, 4).error, SdoAbort::no_sub_index);  // reserved, absent
  EXPECT_EQ(od.get_unsigned(0x1801, 5), 250u);
  EXPECT_EQ(od.get_unsigned(0x1A01, 0), 2u);
  EXPECT_EQ(od.find(0x1A01, 0)->access, Access::rw);
  EXPECT_EQ(od.get_unsigned(0x1A01, 1), 0x60000108u);
  EXPECT_EQ(od.get_unsigned(0x1A01, 2), 0x60010010u);
  EXPECT_EQ(od.get_unsigned(0x1A01, 8), 0u);
  EXPECT_FALSE(od.has_object(0x1800));

  EXPECT_EQ(od.get_unsigned(0x1400, 0), 2u);
  EXPECT_EQ(od.get_unsigned(0x1400, 1), 0x80000201u);  // disabled: bit 31
  EXPECT_EQ(od.get_unsigned(0x1400, 2), 255u);
  EXPECT_EQ(od.read(0x1400, 3).error, SdoAbort::no_sub_index);
  EXPECT_EQ(od.get_unsigned(0x1600, 0), 1u);
  EXPECT_EQ(od.get_unsigned(0x1600, 1), 0x60020020u);

  EXPECT_EQ(engine->tpdo_cob_id(2), 0x281u);
  EXPECT_EQ(engine->tpdo_cob_id(1), std::nullopt);
  EXPECT_EQ(engine->rpdo_cob_id(1), std::nullopt);  // disabled
}

TEST_F(PdoEngineTest, FixedMappingIsConstant) {
  make({pdo(1, 0x181, 255, kU16Mapping)}, {}, {.fixed_cob_ids = true, .fixed_mapping = true});
  EXPECT_EQ(od.find(0x1A00, 0)->access, Access::constant);
  EXPECT_EQ(od.find(0x1A00, 1)->access, Access::constant);
  EXPECT_EQ(od.write(0x1A00, 0, Bytes{0}), SdoAbort::write_read_only);
  EXPECT_EQ(od.find(0x1800, 1)->access, Access::rw);
}

TEST_F(PdoEngineTest, InstallRejectsImpossibleConfiguration) {
  const auto rejects = [&](std::vector<PdoSpec> tpdos, std::vector<PdoSpec> rpdos) {
    EXPECT_THROW(PdoEngine::install(od, tpdos, rpdos, {}), std::invalid_argument);
  };
  rejects({pdo(1, 0x181, 255, {{0x6FFF, 0, 8}})}, {});  // missing object
  rejects({}, {pdo(1, 0x201, 255, {{kU8, 2, 8}})});     // missing sub-index
  rejects({pdo(1, 0x181, 255, {{kU32, 0, 32}, {kU32, 0, 32}, {kU8, 1, 8}})}, {});  // 72 bits
  rejects({pdo(1, 0x181, 255, {{kU16, 0, 12}})}, {});  // not whole bytes
  rejects({pdo(1, 0x181, 255, {{kU16, 0, 32}})}, {});  // more than the object
  rejects({pdo(0, 0x181, 255, {})}, {});
  rejects({pdo(513, 0x181, 255, {})}, {});
  rejects({pdo(1, 0x181, 255, {}), pdo(1, 0x182, 255, {})}, {});  // twice
  rejects({pdo(1, 0x181, 245, {})}, {});                          // reserved type
  rejects({pdo(1, 0x800, 255, {})}, {});                          // not 11 bits
  PdoSpec no_cob_id = pdo(1, 0, 255, {});
  no_cob_id.cob_id.reset();
  rejects({no_cob_id}, {});
  // A refused rig leaves the dictionary untouched.
  rejects({pdo(1, 0x181, 255, kU16Mapping), pdo(2, 0x281, 255, {{0x6FFF, 0, 8}})}, {});
  EXPECT_FALSE(od.has_object(0x1800));
}

TEST_F(PdoEngineTest, StartSendsEventDrivenTpdosOnce) {
  make({pdo(1, 0x181, 255, kU16Mapping), pdo(2, 0x281, 1, kU16Mapping)});
  engine->poll(now, out);
  EXPECT_TRUE(take().empty());  // not operational yet
  engine->start(now, out);
  const Frames frames = take();
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], can::Frame::standard(0x181, {0x34, 0x12}));
  engine->poll(now + 1s, out);
  EXPECT_TRUE(take().empty());  // no change, no event timer
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());
  EXPECT_EQ(engine->counters().tpdos_sent, 1u);
}

TEST_F(PdoEngineTest, EventTimerCadence) {
  PdoSpec spec = pdo(1, 0x181, 254, kU16Mapping);
  spec.event_timer_ms = 100;
  make({spec});
  engine->start(now, out);
  EXPECT_EQ(take().size(), 1u);
  EXPECT_EQ(engine->next_deadline(), kEngineStart + 100ms);
  engine->poll(kEngineStart + 99ms, out);
  EXPECT_TRUE(take().empty());
  for (int period = 1; period <= 3; ++period) {
    engine->poll(kEngineStart + period * 100ms, out);
    const Frames frames = take();
    ASSERT_EQ(frames.size(), 1u) << "period " << period;
    EXPECT_EQ(frames[0], can::Frame::standard(0x181, {0x34, 0x12}));
    EXPECT_EQ(engine->next_deadline(), kEngineStart + (period + 1) * 100ms);
  }
}

TEST_F(PdoEngineTest, ChangeOfStateDuringInhibitGoesOutOnceAtItsEndWithTheLatestValue) {
  PdoSpec spec = pdo(1, 0x181, 255, kU16Mapping);
  spec.inhibit_100us = 100;  // 10 ms
  make({spec});
  engine->start(now, out);
  EXPECT_EQ(take().size(), 1u);

  now = kEngineStart + 2ms;
  set_u16(0x0001);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(engine->next_deadline(), kEngineStart + 10ms);
  now = kEngineStart + 5ms;
  set_u16(0x0002);
  EXPECT_TRUE(take().empty());

  engine->poll(kEngineStart + 10ms, out);
  const Frames frames = take();
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0], can::Frame::standard(0x181, {0x02, 0x00}));
  engine->poll(kEngineStart + 10ms, out);
  engine->poll(kEngineStart + 30ms, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());

  // After the inhibit time a change goes out at once.
  now = kEngineStart + 25ms;
  set_u16(0x0003);
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x181, {0x03, 0x00})}));
}

TEST_F(PdoEngineTest, ChangeUndoneDuringInhibitIsNotSent) {
  PdoSpec spec = pdo(1, 0x181, 255, kU16Mapping);
  spec.inhibit_100us = 100;
  make({spec});
  engine->start(now, out);
  take();
  now = kEngineStart + 1ms;
  set_u16(0x0001);
  now = kEngineStart + 2ms;
  set_u16(0x1234);
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());
  engine->poll(kEngineStart + 10ms, out);
  EXPECT_TRUE(take().empty());
}

TEST_F(PdoEngineTest, SynchronousTpdoEveryNthSync) {
  make({pdo(1, 0x181, 3, kU16Mapping)});
  engine->start(now, out);
  EXPECT_TRUE(take().empty());
  for (int sync = 1; sync <= 9; ++sync) {
    engine->on_sync(kEngineStart + sync * 10ms, out);
    EXPECT_EQ(take().size(), sync % 3 == 0 ? 1u : 0u) << "SYNC " << sync;
  }
  // Change of state does not trigger a synchronous TPDO.
  set_u16(0x4321);
  EXPECT_TRUE(take().empty());
}

TEST_F(PdoEngineTest, AcyclicSynchronousTpdoOnlyWhenChanged) {
  make({pdo(1, 0x181, 0, kU16Mapping)});
  engine->start(now, out);
  EXPECT_TRUE(take().empty());
  engine->on_sync(now, out);  // nothing sent since start: the first SYNC sends
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x181, {0x34, 0x12})}));
  engine->on_sync(now, out);
  EXPECT_TRUE(take().empty());
  set_u16(0x0005);
  EXPECT_TRUE(take().empty());  // waits for the SYNC
  engine->on_sync(now, out);
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x181, {0x05, 0x00})}));
  engine->on_sync(now, out);
  EXPECT_TRUE(take().empty());
}

TEST_F(PdoEngineTest, Bit31DisablesAndClearingItResumes) {
  PdoSpec spec = pdo(1, 0x181, 254, kU16Mapping);
  spec.event_timer_ms = 100;
  make({spec});
  engine->start(now, out);
  take();

  now = kEngineStart + 50ms;
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x80000181)));
  EXPECT_EQ(engine->tpdo_cob_id(1), std::nullopt);
  set_u16(0x0007);
  engine->poll(kEngineStart + 100ms, out);
  engine->on_sync(kEngineStart + 100ms, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());

  now = kEngineStart + 150ms;
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x181)));
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x181, {0x07, 0x00})}));
  EXPECT_EQ(engine->tpdo_cob_id(1), 0x181u);
  EXPECT_EQ(engine->next_deadline(), kEngineStart + 250ms);
}

TEST_F(PdoEngineTest, CobIdChangesOnlyWhileDisabled) {
  make({pdo(1, 0x181, 255, kU16Mapping)});
  engine->start(now, out);
  take();
  EXPECT_EQ(od.write(0x1800, 1, u32(0x190)), SdoAbort::value_range);
  EXPECT_EQ(od.get_unsigned(0x1800, 1), 0x181u);
  EXPECT_FALSE(od.write(0x1800, 1, u32(0x181)));  // the same value is accepted

  ASSERT_FALSE(od.write(0x1800, 1, u32(0x80000181)));
  EXPECT_EQ(od.write(0x1800, 1, u32(0xA0000190)), SdoAbort::value_range);  // 29-bit id
  EXPECT_EQ(od.write(0x1800, 1, u32(0x601)), SdoAbort::value_range);       // restricted (SDO)
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x80000190)));
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x190)));
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x190, {0x34, 0x12})}));
  EXPECT_EQ(engine->tpdo_cob_id(1), 0x190u);
}

TEST_F(PdoEngineTest, FixedCobIdsAllowOnlyBit31ToChange) {
  make({pdo(1, 0x1A1, 255, kU16Mapping)}, {pdo(1, 0x201, 255, kU16Mapping)},
       {.fixed_cob_ids = true, .fixed_mapping = false});
  engine->start(now, out);
  take();
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x800001A1)));
  EXPECT_EQ(od.write(0x1800, 1, u32(0x800001A2)), SdoAbort::value_range);
  EXPECT_EQ(od.write(0x1800, 1, u32(0x1A2)), SdoAbort::value_range);
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x1A1)));
  EXPECT_EQ(take().size(), 1u);
  EXPECT_EQ(od.write(0x1400, 1, u32(0x80000202)), SdoAbort::value_range);
  EXPECT_FALSE(od.write(0x1400, 1, u32(0x80000201)));
  EXPECT_EQ(engine->rpdo_cob_id(1), std::nullopt);
}

TEST_F(PdoEngineTest, InhibitTimeAndTransmissionTypeRules) {
  make({pdo(1, 0x181, 255, kU16Mapping)});
  EXPECT_EQ(od.write(0x1800, 3, le_bytes(20, 2)), SdoAbort::value_range);  // PDO valid
  EXPECT_FALSE(od.write(0x1800, 5, le_bytes(20, 2)));  // the event timer may change any time
  EXPECT_EQ(od.write(0x1800, 2, Bytes{245}), SdoAbort::value_range);
  EXPECT_FALSE(od.write(0x1800, 2, Bytes{254}));
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x80000181)));
  EXPECT_FALSE(od.write(0x1800, 3, le_bytes(20, 2)));
  EXPECT_EQ(od.get_unsigned(0x1800, 3), 20u);
}

TEST_F(PdoEngineTest, RemappingFollowsTheCia301Procedure) {
  make({pdo(1, 0x181, 255, kU16Mapping)});
  engine->start(now, out);
  take();
  EXPECT_EQ(od.write(0x1A00, 0, Bytes{0}), SdoAbort::device_state);  // PDO valid
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x80000181)));
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x60020020)), SdoAbort::device_state);  // sub 0 != 0
  ASSERT_FALSE(od.write(0x1A00, 0, Bytes{0}));
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x6FFF0008)), SdoAbort::no_object);
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x60000208)), SdoAbort::not_mappable);  // no sub 2
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x6001000C)), SdoAbort::not_mappable);  // 12 bits
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x60030008)), SdoAbort::not_mappable);  // write-only
  EXPECT_EQ(od.write(0x1A00, 1, u32(0x60020048)), SdoAbort::pdo_too_long);  // 72 bits
  ASSERT_FALSE(od.write(0x1A00, 1, u32(0x60020020)));
  ASSERT_FALSE(od.write(0x1A00, 2, u32(0x60020020)));
  ASSERT_FALSE(od.write(0x1A00, 3, u32(0x60000108)));
  EXPECT_EQ(od.write(0x1A00, 0, Bytes{9}), SdoAbort::pdo_too_long);
  EXPECT_EQ(od.write(0x1A00, 0, Bytes{3}), SdoAbort::pdo_too_long);  // 72 bits in all
  ASSERT_FALSE(od.write(0x1A00, 0, Bytes{2}));
  ASSERT_FALSE(od.write(0x1800, 1, u32(0x181)));
  EXPECT_EQ(
      take(),
      (Frames{can::Frame::standard(0x181, {0xD4, 0xC3, 0xB2, 0xA1, 0xD4, 0xC3, 0xB2, 0xA1})}));
}

TEST_F(PdoEngineTest, RpdoWritesMappedObjectsLittleEndian) {
  make({}, {pdo(1, 0x201, 255, {{kU8, 1, 8}, {kU16, 0, 16}, {kU32, 0, 32}})});
  engine->start(now, out);
  const auto frame = can::Frame::standard(0x201, {0x99, 0x34, 0x12, 0x78, 0x56, 0x34, 0x12});
  EXPECT_EQ(engine->on_frame(frame, now), PdoEngine::RxResult::written);
  EXPECT_EQ(od.get_unsigned(kU8, 1), 0x99u);
  EXPECT_EQ(od.get_unsigned(kU16, 0), 0x1234u);
  EXPECT_EQ(od.get_unsigned(kU32, 0), 0x12345678u);
  // Extra bytes are accepted.
  const auto longer = can::Frame::standard(0x201, {0x01, 0x02, 0x00, 0x03, 0x00, 0x00, 0x00, 0xEE});
  EXPECT_EQ(engine->on_frame(longer, now), PdoEngine::RxResult::written);
  EXPECT_EQ(od.get_unsigned(kU32, 0), 3u);
  EXPECT_EQ(engine->counters().rpdos_written, 2u);
  EXPECT_EQ(engine->on_frame(can::Frame::standard(0x202, {1}), now), PdoEngine::RxResult::not_mine);
  EXPECT_EQ(engine->on_frame(can::Frame::make(0x201, can::FrameFlags::extended, {1}), now),
            PdoEngine::RxResult::not_mine);
}

TEST_F(PdoEngineTest, PartlyMappedNumberGetsZeros) {
  make({}, {pdo(1, 0x201, 255, {{kU32, 0, 16}})});
  engine->start(now, out);
  EXPECT_EQ(engine->on_frame(can::Frame::standard(0x201, {0xCD, 0xAB}), now),
            PdoEngine::RxResult::written);
  EXPECT_EQ(od.get_unsigned(kU32, 0), 0x0000ABCDu);
}

TEST_F(PdoEngineTest, ShortRpdoIsALengthError) {
  make({}, {pdo(1, 0x201, 255, {{kU8, 1, 8}, {kU16, 0, 16}})});
  engine->start(now, out);
  EXPECT_EQ(engine->on_frame(can::Frame::standard(0x201, {0x01, 0x02}), now),
            PdoEngine::RxResult::length_error);
  EXPECT_EQ(od.get_unsigned(kU8, 1), 0x11u);  // untouched
  EXPECT_EQ(od.get_unsigned(kU16, 0), 0x1234u);
  EXPECT_EQ(engine->counters().rpdo_length_errors, 1u);
  EXPECT_EQ(engine->counters().rpdos_written, 0u);
}

TEST_F(PdoEngineTest, RpdoMappingRefusesReadOnlyObjects) {
  make({}, {pdo(1, 0x201, 255, {{kU8, 1, 8}})});
  ASSERT_FALSE(od.write(0x1400, 1, u32(0x80000201)));
  ASSERT_FALSE(od.write(0x1600, 0, Bytes{0}));
  EXPECT_EQ(od.write(0x1600, 1, u32(0x60040008)), SdoAbort::not_mappable);
  EXPECT_FALSE(od.write(0x1600, 1, u32(0x60030008)));  // write-only is fine for an RPDO
}

TEST_F(PdoEngineTest, NotOperationalSendsAndWritesNothing) {
  PdoSpec tpdo = pdo(1, 0x181, 255, kU16Mapping);
  tpdo.event_timer_ms = 10;
  make({tpdo, pdo(2, 0x281, 1, kU16Mapping)}, {pdo(1, 0x201, 255, {{kU8, 1, 8}})});
  const auto rpdo = can::Frame::standard(0x201, {0x55});

  EXPECT_EQ(engine->on_frame(rpdo, now), PdoEngine::RxResult::ignored);
  engine->on_sync(now, out);
  set_u16(0x0001);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());

  engine->start(now, out);
  EXPECT_EQ(take().size(), 1u);
  engine->stop();
  EXPECT_EQ(engine->next_deadline(), TimePoint::max());
  EXPECT_EQ(engine->on_frame(rpdo, now), PdoEngine::RxResult::ignored);
  EXPECT_EQ(od.get_unsigned(kU8, 1), 0x11u);
  engine->on_sync(now, out);
  set_u16(0x0002);
  engine->poll(now + 1s, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(engine->counters().rpdos_written, 0u);
}

TEST_F(PdoEngineTest, RestartAfterStopSendsCurrentValuesAgain) {
  make({pdo(1, 0x181, 255, kU16Mapping)});
  engine->start(now, out);
  take();
  engine->stop();
  set_u16(0x0042);
  engine->start(now + 1s, out);
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x181, {0x42, 0x00})}));
}

}  // namespace
}  // namespace canbridge::sim
