// The gateway's PDO Packet work driven directly, with injected times and no I/O: fragments in,
// payloads for the surface and fragments for the bus out, the queue's bound and batching, outcome
// reports, node restarts and deadlines.
#include "bridge/gateway_pdop_work.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "canopen/pdop.hpp"
#include "routing/node_map.hpp"
#include "tests/bridge/rpdop_test_helpers.hpp"
#include "tests/support/fake_payload_sink.hpp"

namespace canbridge::bridge {
namespace {

namespace pdop = canopen::pdop;
using namespace std::chrono_literals;
using rpdop_test::Bytes;
using rpdop_test::counting;
using rpdop_test::Frames;
using TimePoint = GatewayPdopWork::TimePoint;

constexpr ModuleId kModule = 1;
constexpr canopen::NodeId kLocal = 1, kSurface = 3, kOtherLocal = 2, kOtherSurface = 4;
const TimePoint t0 = TimePoint{} + 1000s;
constexpr std::chrono::nanoseconds kUnix{0};

class GatewayPdopWorkTest : public ::testing::Test {
 protected:
  GatewayPdopWorkTest() {
    EXPECT_TRUE(
        map.add_module(kModule, {{kLocal, kSurface}, {kOtherLocal, kOtherSurface}}, IdProfile::pdop)
            .empty());
  }
  GatewayPdopWork make(std::size_t max_queued_bytes = GatewayPdopWork::kDefaultMaxQueuedBytes) {
    GatewayPdopWork::Module m;
    m.id = kModule;
    return GatewayPdopWork(map, {m}, "test", max_queued_bytes);
  }
  // Every frame of `frames` taken by the core.
  static void feed(GatewayPdopWork& work, const Frames& frames, TimePoint at) {
    for (const can::Frame& f : frames) ASSERT_TRUE(work.on_bus_frame(0, f, at, kUnix));
  }
  static Frames tpdop(canopen::NodeId node, unsigned tpdo, const Bytes& bytes) {
    return pdop::fragment(pdop::tpdo_base(tpdo), node, bytes);
  }
  static can::Frame ack(canopen::NodeId node, pdop::AckStatus status, std::uint16_t received,
                        std::uint8_t credit) {
    return pdop::encode_ack(node, pdop::Ack{1, status, received, credit});
  }
  // The fragments sent to the bus since the last call, all modules (all module 0 here).
  static Frames take_bus_frames(GatewayPdopWork& work) {
    Frames out;
    for (const auto& batch : work.bus_frames()) {
      EXPECT_EQ(batch.module_index, 0u);
      out.insert(out.end(), batch.frames.begin(), batch.frames.end());
    }
    work.bus_frames().clear();
    return out;
  }
  static v1::PdopPackets rpdop(std::uint32_t surface_node, const Bytes& bytes,
                               std::uint64_t request_id) {
    v1::PdopPackets packets;
    v1::PdopPacket& p = *packets.add_packets();
    p.set_module_id(kModule);
    p.set_surface_node(surface_node);
    p.set_pdo(1);
    p.set_data(bytes.data(), bytes.size());
    p.set_request_id(request_id);
    return packets;
  }

  NodeMap map;
};

TEST_F(GatewayPdopWorkTest, ATpdopPacketBecomesOnePayloadUnderTheSurfaceId) {
  GatewayPdopWork work = make();
  ASSERT_TRUE(work.active());
  const Bytes data = counting(20);  // 3 fragments
  feed(work, tpdop(kLocal, 2, data), t0);
  // Not PDOP traffic: goes on to the translator.
  EXPECT_FALSE(work.on_bus_frame(0, can::Frame::standard(0x700 + kLocal, {0x05}), t0, kUnix));

  const v1::Payload* payload = work.next_payload();
  ASSERT_NE(payload, nullptr);
  ASSERT_TRUE(payload->has_pdop_packets());
  ASSERT_EQ(payload->pdop_packets().packets_size(), 1);
  const v1::PdopPacket& p = payload->pdop_packets().packets(0);
  EXPECT_EQ(p.module_id(), kModule);
  EXPECT_EQ(p.local_node(), kLocal);
  EXPECT_EQ(p.surface_node(), kSurface);
  EXPECT_EQ(p.pdo(), 2u);
  EXPECT_EQ(p.data(), std::string(data.begin(), data.end()));
  EXPECT_EQ(work.counters().packets, 1u);
  EXPECT_EQ(work.counters().packet_bytes, 20u);
  EXPECT_EQ(work.counters().fragments, 3u);
  work.pop_payload();
  EXPECT_EQ(work.next_payload(), nullptr);
  EXPECT_EQ(work.queued_bytes(), 0u);
}

TEST_F(GatewayPdopWorkTest, SmallPacketsShareAPayloadUpToTheBatchSize) {
  GatewayPdopWork work = make();
  // Each one-frame packet of 8 bytes counts 32 bytes: 64 fill one 2048-byte payload.
  for (std::uint8_t i = 0; i < 100; ++i) feed(work, tpdop(kLocal, 1, counting(8, i)), t0);
  EXPECT_EQ(work.queued_payloads(), 2u);
  const v1::Payload* first = work.next_payload();
  ASSERT_NE(first, nullptr);
  ASSERT_EQ(first->pdop_packets().packets_size(), 64);
  EXPECT_EQ(first->pdop_packets().packets(63).data(), std::string(1, '\x3f') + "@ABCDEF");
  work.pop_payload();
  EXPECT_EQ(work.next_payload()->pdop_packets().packets_size(), 36);
  EXPECT_EQ(work.counters().packets, 100u);
}

TEST_F(GatewayPdopWorkTest, AFullQueueRefusesPacketsAndCountsThem) {
  GatewayPdopWork work = make(100);  // three 32-byte packets fit
  for (std::uint8_t i = 0; i < 4; ++i) feed(work, tpdop(kLocal, 1, counting(8, i)), t0);
  EXPECT_EQ(work.counters().packets, 3u);
  EXPECT_EQ(work.counters().refused, 1u);
  EXPECT_EQ(work.queued_bytes(), 96u);
  // Sent: room again.
  work.pop_payload();
  feed(work, tpdop(kLocal, 1, counting(8, 9)), t0);
  EXPECT_EQ(work.counters().packets, 4u);
  EXPECT_EQ(work.counters().refused, 1u);
  // A payload the link can never take is dropped, counted with the refusals.
  work.refuse_payload(1 << 30);
  EXPECT_EQ(work.next_payload(), nullptr);
  EXPECT_EQ(work.counters().refused, 2u);
}

// produce(): payloads go to the session reliable and in order while it has room; a full resend
// buffer keeps them queued, and one the resend buffer could never hold is refused, not waited for.
TEST_F(GatewayPdopWorkTest, ProduceSendsReliablyInOrderAndRefusesWhatNoBufferHolds) {
  GatewayPdopWork work = make();
  for (std::uint8_t i = 0; i < 100; ++i) feed(work, tpdop(kLocal, 1, counting(8, i)), t0);
  ASSERT_EQ(work.queued_payloads(), 2u);
  test::FakeSink sink;
  sink.reliable_room_ = false;
  work.produce(sink, 1 << 20);
  EXPECT_TRUE(sink.sent.empty());
  EXPECT_EQ(work.queued_payloads(), 2u);
  sink.reliable_room_ = true;
  work.produce(sink, 1 << 20);
  ASSERT_EQ(sink.sent.size(), 2u);
  for (const auto& sent : sink.sent) EXPECT_TRUE(sent.reliable);
  v1::Payload first;
  ASSERT_TRUE(first.ParseFromString(sink.sent[0].bytes));
  EXPECT_EQ(first.pdop_packets().packets_size(), 64);  // the older payload first
  EXPECT_EQ(work.queued_payloads(), 0u);
  // Larger than the resend buffer: refused and counted, and the next one still goes.
  feed(work, tpdop(kLocal, 1, counting(8, 1)), t0);
  work.produce(sink, 16);
  EXPECT_EQ(sink.sent.size(), 2u);
  EXPECT_EQ(work.counters().refused, 1u);
  EXPECT_EQ(work.queued_payloads(), 0u);
  EXPECT_EQ(sink.reliable_calls_while_full_, 0u);
}

TEST_F(GatewayPdopWorkTest, AnRpdopPacketIsSegmentedByTheNodesCreditAndItsOutcomeReported) {
  GatewayPdopWork work = make();
  const Bytes data = counting(100);  // 13 fragments; the first window is 4
  const Frames all = pdop::fragment(pdop::rpdo_base(1), kLocal, data);
  work.on_rpdop_packets(rpdop(kSurface, data, 7), t0);
  EXPECT_EQ(take_bus_frames(work), Frames(all.begin(), all.begin() + 4));
  EXPECT_EQ(work.next_payload(), nullptr);  // no outcome yet

  ASSERT_TRUE(work.on_bus_frame(0, ack(kLocal, pdop::AckStatus::in_progress, 4, 2), t0, kUnix));
  EXPECT_EQ(take_bus_frames(work), Frames(all.begin() + 4, all.begin() + 6));
  ASSERT_TRUE(work.on_bus_frame(0, ack(kLocal, pdop::AckStatus::in_progress, 6, 0), t0, kUnix));
  EXPECT_TRUE(take_bus_frames(work).empty());  // credit 0: wait
  ASSERT_TRUE(work.on_bus_frame(0, ack(kLocal, pdop::AckStatus::in_progress, 6, 255), t0, kUnix));
  EXPECT_EQ(take_bus_frames(work), Frames(all.begin() + 6, all.end()));
  ASSERT_TRUE(work.on_bus_frame(0, ack(kLocal, pdop::AckStatus::complete, 13, 4), t0 + 5ms, kUnix));

  const v1::Payload* report = work.next_payload();
  ASSERT_NE(report, nullptr);
  ASSERT_EQ(report->pdop_reports().outcomes_size(), 1);
  const v1::RpdopOutcome& o = report->pdop_reports().outcomes(0);
  EXPECT_EQ(o.request_id(), 7u);
  EXPECT_EQ(o.surface_node(), kSurface);
  EXPECT_EQ(o.result(), v1::RpdopOutcome::COMPLETE);
  EXPECT_EQ(o.fragments(), 13u);
  EXPECT_EQ(work.counters().rpdop_packets, 1u);
  EXPECT_EQ(work.counters().rpdop_complete, 1u);
  EXPECT_EQ(work.counters().rpdop_failed, 0u);
}

TEST_F(GatewayPdopWorkTest, AnRpdopPacketForNoPdopNodeIsRefusedWithAnOutcome) {
  GatewayPdopWork work = make();
  work.on_rpdop_packets(rpdop(20, counting(8), 9), t0);  // surface node 20: not this gateway's
  EXPECT_TRUE(take_bus_frames(work).empty());
  const v1::Payload* report = work.next_payload();
  ASSERT_NE(report, nullptr);
  ASSERT_EQ(report->pdop_reports().outcomes_size(), 1);
  EXPECT_EQ(report->pdop_reports().outcomes(0).request_id(), 9u);
  EXPECT_EQ(report->pdop_reports().outcomes(0).result(), v1::RpdopOutcome::REFUSED_ADDRESS);
  EXPECT_EQ(work.counters().rpdop_failed, 1u);
}

TEST_F(GatewayPdopWorkTest, ANodeRestartDiscardsItsOpenPacketsInBothDirections) {
  GatewayPdopWork work = make();
  const Frames in = tpdop(kLocal, 1, counting(20));
  feed(work, Frames(in.begin(), in.begin() + 2), t0);  // open: 2 of 3 fragments
  work.on_rpdop_packets(rpdop(kSurface, counting(100), 5), t0);
  take_bus_frames(work);
  feed(work, tpdop(kOtherLocal, 1, counting(20)), t0);  // another node's packet is complete

  NodeEvent booted;
  booted.kind = NodeEvent::Kind::booted;
  booted.module_index = 0;
  booted.local = kLocal;
  work.on_node_event(booted, t0 + 1ms);
  // The transfer to the node is aborted on the bus.
  EXPECT_EQ(take_bus_frames(work), Frames{pdop::abort_frame(pdop::rpdo_base(1), kLocal)});

  std::vector<v1::PdopDiscard> discards;
  std::vector<v1::RpdopOutcome> outcomes;
  int packets = 0;
  while (const v1::Payload* p = work.next_payload()) {
    packets += p->pdop_packets().packets_size();
    for (const auto& d : p->pdop_reports().discards()) discards.push_back(d);
    for (const auto& o : p->pdop_reports().outcomes()) outcomes.push_back(o);
    work.pop_payload();
  }
  EXPECT_EQ(packets, 1);  // node 2's
  ASSERT_EQ(discards.size(), 1u);
  EXPECT_EQ(discards[0].surface_node(), kSurface);
  EXPECT_EQ(discards[0].reason(), v1::PdopDiscard::NODE_RESTART);
  EXPECT_EQ(discards[0].fragments(), 2u);
  ASSERT_EQ(outcomes.size(), 1u);
  EXPECT_EQ(outcomes[0].request_id(), 5u);
  EXPECT_EQ(outcomes[0].result(), v1::RpdopOutcome::CANCELLED);
  EXPECT_EQ(work.counters().discards, 1u);
  EXPECT_EQ(work.counters().rpdop_failed, 1u);
  // Only the segmenter still waits on time, for the node to confirm the abort; then nothing.
  EXPECT_TRUE(work.next_deadline().has_value());
  ASSERT_TRUE(
      work.on_bus_frame(0, ack(kLocal, pdop::AckStatus::sender_abort, 0, 0), t0 + 2ms, kUnix));
  EXPECT_EQ(work.next_deadline(), std::nullopt);
}

TEST_F(GatewayPdopWorkTest, AnOpenPacketReportsItsDeadlineAndTimesOutAtIt) {
  GatewayPdopWork work = make();
  EXPECT_EQ(work.next_deadline(), std::nullopt);
  const Frames in = tpdop(kLocal, 1, counting(20));
  feed(work, Frames(in.begin(), in.begin() + 1), t0);
  const auto timeout = PdopReassemblerOptions{}.fragment_timeout;
  ASSERT_EQ(work.next_deadline(), t0 + timeout);

  work.tick(t0 + timeout - 1ms, kUnix);
  EXPECT_EQ(work.next_payload(), nullptr);
  EXPECT_EQ(work.next_deadline(), t0 + timeout);

  work.tick(t0 + timeout, kUnix);
  const v1::Payload* report = work.next_payload();
  ASSERT_NE(report, nullptr);
  ASSERT_EQ(report->pdop_reports().discards_size(), 1);
  EXPECT_EQ(report->pdop_reports().discards(0).reason(), v1::PdopDiscard::TIMEOUT);
  EXPECT_EQ(work.next_deadline(), std::nullopt);

  // The segmenter's deadline too: an unacknowledged window asks again after ack_timeout.
  work.on_rpdop_packets(rpdop(kSurface, counting(100), 1), t0);
  const auto deadline = work.next_deadline();
  ASSERT_TRUE(deadline.has_value());
  EXPECT_GT(*deadline, t0);
  take_bus_frames(work);
  work.tick(*deadline, kUnix);
  EXPECT_EQ(take_bus_frames(work), Frames{pdop::ack_request(kLocal)});
}

TEST_F(GatewayPdopWorkTest, PdopNodesGoAheadOfQueuedPacketsWhenAnnounced) {
  GatewayPdopWork work = make();
  feed(work, tpdop(kLocal, 1, counting(8)), t0);
  work.announce_nodes();
  const v1::Payload* first = work.next_payload();
  ASSERT_NE(first, nullptr);
  ASSERT_TRUE(first->has_pdop_nodes());
  ASSERT_EQ(first->pdop_nodes().nodes_size(), 2);
  EXPECT_EQ(first->pdop_nodes().nodes(0).surface_node(), kSurface);
  EXPECT_TRUE(first->pdop_nodes().nodes(0).whole());
  work.pop_payload();
  EXPECT_TRUE(work.next_payload()->has_pdop_packets());
}

}  // namespace
}  // namespace canbridge::bridge
