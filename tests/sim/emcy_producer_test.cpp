// The EMCY producer (CiA 301 1001h/1003h/1014h/1015h) and the QD-CANopen state-change flags
// (seeds/003), frame by frame with injected time.
#include "sim/emcy_producer.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <utility>

#include "canopen/sdo_abort.hpp"
#include "sim/qd_event_flags.hpp"

namespace canbridge::sim {
namespace {

using namespace std::chrono_literals;
using canopen::SdoAbort;
using Bytes = std::vector<std::uint8_t>;
using Frames = std::vector<can::Frame>;
using TimePoint = EmcyProducer::TimePoint;

const TimePoint t0 = TimePoint{} + 1000s;
constexpr canopen::NodeId kNode = 1;

EmcySpec spec_with_inhibit(std::uint16_t inhibit_100us) {
  EmcySpec spec;
  spec.inhibit_100us = inhibit_100us;
  return spec;
}

can::Frame emcy(std::uint32_t id, std::uint16_t code, std::uint8_t reg,
                EmcyProducer::ManufacturerField mfr = {}) {
  return can::Frame::standard(
      id, {static_cast<std::uint8_t>(code), static_cast<std::uint8_t>(code >> 8), reg, mfr[0],
           mfr[1], mfr[2], mfr[3], mfr[4]});
}

// A node's dictionary with the producer (and optionally the qd flags) behind its write guard and
// listener, as the node wires them.
class EmcyTest : public ::testing::Test {
 protected:
  void make(EmcySpec spec = {}) {
    producer = std::make_unique<EmcyProducer>(od, kNode, spec);
    od.set_write_guard([this](const OdEntry& entry, std::span<const std::uint8_t> data) {
      if (const auto error = producer->check_write(entry, data)) return error;
      return flags ? flags->check_write(entry, data) : std::error_code{};
    });
    od.set_write_listener([this](const OdEntry& entry) {
      producer->on_written(entry, now, out);
      if (flags) flags->on_written(entry, now, out);
    });
  }
  void make_qd(std::chrono::milliseconds holdoff) {
    make();
    flags = std::make_unique<QdEventFlags>(od, *producer, holdoff);
  }

  std::uint32_t value(std::uint16_t index, std::uint8_t sub = 0) const {
    return od.get_unsigned(index, sub).value_or(0xDEADBEEF);
  }
  Frames take() { return std::exchange(out, {}); }

  ObjectDictionary od;
  std::unique_ptr<EmcyProducer> producer;
  std::unique_ptr<QdEventFlags> flags;
  TimePoint now = t0;
  Frames out;
};

// ---- EMCY producer --------------------------------------------------------------------------

TEST_F(EmcyTest, AddsItsObjects) {
  make(spec_with_inhibit(25));
  EXPECT_EQ(value(0x1014), 0x81u);
  EXPECT_EQ(od.find(0x1014, 0)->access, Access::rw);
  EXPECT_EQ(od.find(0x1014, 0)->type, DataType::unsigned32);
  EXPECT_EQ(value(0x1015), 25u);
  EXPECT_EQ(od.find(0x1015, 0)->type, DataType::unsigned16);
  EXPECT_EQ(value(0x1003, 0), 0u);
  EXPECT_EQ(od.find(0x1003, 0)->access, Access::rw);
  EXPECT_EQ(od.find(0x1003, 8)->access, Access::ro);
  EXPECT_EQ(od.read(0x1003, 9).error, SdoAbort::no_sub_index);
  EXPECT_EQ(value(0x1001), 0u);
  EXPECT_EQ(od.find(0x1001, 0)->type, DataType::unsigned8);
}

TEST_F(EmcyTest, KeepsTheNodesErrorRegister) {
  od.add_unsigned(0x1001, 0, Access::ro, 0x20, 1);
  make();
  EXPECT_EQ(value(0x1001), 0x20u);
}

TEST_F(EmcyTest, FrameLayoutAndErrorRegister) {
  make();
  producer->raise(0x8210, 0x10, {1, 2, 3, 4, 5}, now, out);
  EXPECT_EQ(take(), (Frames{can::Frame::standard(0x81, {0x10, 0x82, 0x11, 1, 2, 3, 4, 5})}));
  EXPECT_EQ(value(0x1001), 0x11u);  // communication error + generic error
  producer->raise(0x3110, 0x04, {}, now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x3110, 0x15)}));
  EXPECT_EQ(producer->counters().sent, 2u);
}

TEST_F(EmcyTest, HistoryIsNewestFirstAndWritingZeroClearsIt) {
  make();
  producer->raise(0x1000, 0, {0xAA, 0xBB, 0, 0, 0}, now, out);
  producer->raise(0x2000, 0, {}, now, out);
  producer->raise(0x3000, 0, {0x01, 0x02, 0x03, 0, 0}, now, out);
  EXPECT_EQ(value(0x1003, 0), 3u);
  EXPECT_EQ(value(0x1003, 1), 0x02013000u);  // code | (mfr0 | mfr1 << 8) << 16
  EXPECT_EQ(value(0x1003, 2), 0x00002000u);
  EXPECT_EQ(value(0x1003, 3), 0xBBAA1000u);
  EXPECT_EQ(value(0x1003, 4), 0u);

  EXPECT_EQ(od.write(0x1003, 0, Bytes{2}), SdoAbort::value_range);
  EXPECT_EQ(od.write(0x1003, 1, Bytes{0, 0, 0, 0}), SdoAbort::write_read_only);
  ASSERT_FALSE(od.write(0x1003, 0, Bytes{0}));
  EXPECT_EQ(value(0x1003, 0), 0u);
  EXPECT_EQ(value(0x1003, 1), 0u);
  EXPECT_EQ(value(0x1003, 3), 0u);
}

TEST_F(EmcyTest, HistoryKeepsTheNewestEight) {
  make();
  for (std::uint16_t code = 1; code <= 10; ++code) producer->raise(code, 0, {}, now, out);
  EXPECT_EQ(value(0x1003, 0), 8u);
  EXPECT_EQ(value(0x1003, 1), 10u);
  EXPECT_EQ(value(0x1003, 8), 3u);
}

TEST_F(EmcyTest, InhibitTimeQueuesAndSendsAtItsEnd) {
  make(spec_with_inhibit(100));  // 10 ms
  producer->raise(0x1000, 0, {}, t0, out);
  EXPECT_EQ(take().size(), 1u);
  producer->raise(0x2000, 0, {}, t0 + 1ms, out);
  producer->raise(0x3000, 0x02, {}, t0 + 2ms, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(producer->next_deadline(), t0 + 10ms);
  producer->poll(t0 + 9ms, out);
  EXPECT_TRUE(take().empty());
  producer->poll(t0 + 10ms, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x2000, 0x01)}));  // 1001h as it was when raised
  EXPECT_EQ(producer->next_deadline(), t0 + 20ms);
  producer->poll(t0 + 20ms, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x3000, 0x03)}));
  EXPECT_EQ(producer->next_deadline(), TimePoint::max());
  EXPECT_EQ(producer->counters().sent, 3u);
  EXPECT_EQ(producer->counters().queued, 2u);
}

TEST_F(EmcyTest, QueueOverflowIsCounted) {
  make(spec_with_inhibit(100));
  for (std::uint16_t code = 1; code <= 10; ++code) producer->raise(code, 0, {}, t0, out);
  EXPECT_EQ(take().size(), 1u);
  EXPECT_EQ(producer->counters().queued, 8u);
  EXPECT_EQ(producer->counters().dropped, 1u);
  producer->poll(t0 + 1s, out);  // one per inhibit time
  EXPECT_EQ(take(), (Frames{emcy(0x81, 2, 0x01)}));
}

TEST_F(EmcyTest, DisabledWhileStoppedChangesStateButSendsNothing) {
  make(spec_with_inhibit(100));
  producer->raise(0x1000, 0, {}, t0, out);
  producer->raise(0x2000, 0, {}, t0, out);  // queued
  take();
  producer->set_enabled(false);
  EXPECT_EQ(producer->next_deadline(), TimePoint::max());  // queue discarded
  producer->raise(0x5000, 0x20, {}, t0 + 1s, out);
  producer->poll(t0 + 2s, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(value(0x1001), 0x21u);
  EXPECT_EQ(value(0x1003, 1), 0x5000u);
  producer->set_enabled(true);
  producer->raise(0x6000, 0, {}, t0 + 3s, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x6000, 0x21)}));
}

TEST_F(EmcyTest, CobIdBit31DisablesTheEmcy) {
  make();
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x80000081, 4)));
  producer->raise(0x1000, 0, {}, now, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(value(0x1001), 0x01u);
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x81, 4)));
  EXPECT_EQ(od.write(0x1014, 0, le_bytes(0x90, 4)), SdoAbort::value_range);        // while valid
  EXPECT_EQ(od.write(0x1014, 0, le_bytes(0x20000081, 4)), SdoAbort::value_range);  // 29-bit
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x80000090, 4)));
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x90, 4)));
  producer->raise(0x2000, 0, {}, now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x90, 0x2000, 0x01)}));
}

TEST_F(EmcyTest, ResetErrorsSendsCodeZero) {
  make();
  producer->raise(0x3110, 0x04, {}, now, out);
  take();
  producer->reset_errors(now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x0000, 0x00)}));
  EXPECT_EQ(value(0x1001), 0u);
  EXPECT_EQ(value(0x1003, 0), 1u);  // the history stays
}

TEST_F(EmcyTest, ClearErrorKeepsOtherErrorsIndicated) {
  make();
  producer->raise(0x3110, 0x04, {}, now, out);
  producer->raise(0xF001, 0x80, {}, now, out);
  take();
  EXPECT_EQ(value(0x1001), 0x85u);
  producer->clear_error(0xF000, 0x80, {}, now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF000, 0x05)}));
  producer->clear_error(0x0000, 0x04, {}, now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0x0000, 0x00)}));
  // A generic-only error keeps bit 0 when other bits go.
  producer->raise(0x1000, 0, {}, now, out);
  producer->raise(0x3110, 0x04, {}, now, out);
  producer->clear_error(0x0000, 0x04, {}, now, out);
  EXPECT_EQ(value(0x1001), 0x01u);
}

TEST_F(EmcyTest, CobIdFollowsTheNodeIdWhenDefault) {
  make();
  producer->set_node_id(5);
  EXPECT_EQ(value(0x1014), 0x85u);
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x80000085, 4)));
  producer->set_node_id(6);
  EXPECT_EQ(value(0x1014), 0x80000086u);  // bit 31 kept
  od.restore_initial(0x1000, 0x1FFF);
  EXPECT_EQ(value(0x1014), 0x86u);  // the reset value followed too
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x80000100, 4)));
  ASSERT_FALSE(od.write(0x1014, 0, le_bytes(0x100, 4)));
  producer->set_node_id(7);
  EXPECT_EQ(value(0x1014), 0x100u);  // configured: stays
  producer->raise(0x1000, 0, {}, now, out);
  EXPECT_EQ(take().at(0).id, 0x100u);
}

// ---- qd state-change flags ------------------------------------------------------------------

TEST_F(EmcyTest, QdFlagSendsFxxxWithErrorRegisterBit7) {
  make_qd(100ms);
  EXPECT_EQ(value(QdEventFlags::kHoldoffTime), 100u);
  EXPECT_EQ(od.find(QdEventFlags::kEventResetRegister, 0)->type, DataType::unsigned16);
  EXPECT_EQ(flags->code(), 0xF000u);
  flags->flag(0, now, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF001, 0x81)}));
  EXPECT_EQ(flags->flags(), 0x0001u);
  EXPECT_EQ(flags->code(), 0xF001u);
  EXPECT_EQ(value(QdEventFlags::kEventResetRegister), 0x0001u);  // reads the flags
}

TEST_F(EmcyTest, QdSameFlagAgainSendsNothing) {
  make_qd(100ms);
  flags->flag(3, t0, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF008, 0x81)}));
  flags->flag(3, t0 + 1s, out);
  flags->poll(t0 + 2s, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(flags->next_deadline(), TimePoint::max());
}

TEST_F(EmcyTest, QdChangesDuringHoldoffAreCoalesced) {
  make_qd(100ms);
  flags->flag(0, t0, out);
  EXPECT_EQ(take().size(), 1u);
  flags->flag(1, t0 + 10ms, out);
  flags->flag(2, t0 + 20ms, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(flags->next_deadline(), t0 + 100ms);
  flags->poll(t0 + 99ms, out);
  EXPECT_TRUE(take().empty());
  flags->poll(t0 + 100ms, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF007, 0x81)}));
  flags->poll(t0 + 200ms, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(flags->next_deadline(), TimePoint::max());
}

TEST_F(EmcyTest, QdEventResetRegisterClearsFlagsAndAnnouncesTheNewPattern) {
  make_qd(100ms);
  flags->flag(0, t0, out);
  flags->flag(1, t0 + 100ms, out);
  EXPECT_EQ(take().size(), 2u);

  now = t0 + 200ms;
  ASSERT_FALSE(od.write(QdEventFlags::kEventResetRegister, 0, le_bytes(0x0001, 2)));
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF002, 0x81)}));  // not 0000h: the new pattern
  EXPECT_EQ(flags->flags(), 0x0002u);
  EXPECT_EQ(value(QdEventFlags::kEventResetRegister), 0x0002u);

  // Re-armed: subsystem 0 is announced again.
  flags->flag(0, t0 + 300ms, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF003, 0x81)}));

  now = t0 + 400ms;
  ASSERT_FALSE(od.write(QdEventFlags::kEventResetRegister, 0, le_bytes(0xFFFF, 2)));
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF000, 0x00)}));  // no other error: 1001h cleared
  EXPECT_EQ(value(0x1001), 0u);
  EXPECT_EQ(flags->flags(), 0u);
}

TEST_F(EmcyTest, QdClearDuringHoldoffWaitsForItsEnd) {
  make_qd(100ms);
  flags->flag(0, t0, out);
  take();
  now = t0 + 50ms;
  ASSERT_FALSE(od.write(QdEventFlags::kEventResetRegister, 0, le_bytes(0x0001, 2)));
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(flags->next_deadline(), t0 + 100ms);
  flags->poll(t0 + 100ms, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF000, 0x00)}));
}

TEST_F(EmcyTest, QdFlagSetAndClearedWithinHoldoffIsNoChange) {
  make_qd(100ms);
  flags->flag(0, t0, out);
  take();
  flags->flag(1, t0 + 10ms, out);
  now = t0 + 20ms;
  ASSERT_FALSE(od.write(QdEventFlags::kEventResetRegister, 0, le_bytes(0x0002, 2)));
  flags->poll(t0 + 100ms, out);
  EXPECT_TRUE(take().empty());  // still F001h, already announced
}

TEST_F(EmcyTest, QdKeepsOtherErrorsInTheErrorRegister) {
  make_qd(0ms);
  producer->raise(0x3110, 0x04, {}, now, out);
  flags->flag(5, now, out);
  EXPECT_EQ(value(0x1001), 0x85u);
  take();
  ASSERT_FALSE(od.write(QdEventFlags::kEventResetRegister, 0, le_bytes(0x0020, 2)));
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF000, 0x05)}));
}

TEST_F(EmcyTest, QdOutOfRangeIgnoredAndResetIsSilent) {
  make_qd(100ms);
  flags->flag(12, now, out);
  EXPECT_TRUE(take().empty());
  EXPECT_EQ(flags->flags(), 0u);
  flags->flag(11, t0, out);
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF800, 0x81)}));
  flags->flag(4, t0 + 10ms, out);  // waiting for the hold-off
  flags->reset();
  EXPECT_EQ(flags->flags(), 0u);
  EXPECT_EQ(flags->code(), 0xF000u);
  EXPECT_EQ(flags->next_deadline(), TimePoint::max());
  flags->poll(t0 + 1s, out);
  EXPECT_TRUE(take().empty());
  // After the reset a change is announced at once.
  flags->flag(4, t0 + 20ms, out);
  EXPECT_EQ(take().size(), 1u);
}

TEST_F(EmcyTest, QdHoldoffTimeIsAnObject) {
  make_qd(100ms);
  flags->flag(0, t0, out);
  flags->flag(1, t0 + 10ms, out);
  take();
  now = t0 + 30ms;
  ASSERT_FALSE(od.write(QdEventFlags::kHoldoffTime, 0, le_bytes(20, 2)));  // already over
  EXPECT_EQ(take(), (Frames{emcy(0x81, 0xF003, 0x81)}));
  flags->flag(2, t0 + 40ms, out);
  EXPECT_EQ(flags->next_deadline(), t0 + 50ms);
}

}  // namespace
}  // namespace canbridge::sim
