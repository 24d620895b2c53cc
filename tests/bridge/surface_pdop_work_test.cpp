// The surface's PDO Packet work (bridge/surface_pdop_work.hpp) on its own, with injected time: a
// gateway's node list decides who owns which pdop node and how its packets cross; a master's
// RPDOP packet goes to its owner's gateway as one payload, or is answered at once when that link
// is down; outcomes and discards are counted; TPDOP packets are judged and counted.
#include "bridge/surface_pdop_work.hpp"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;

const SurfacePdopWork::TimePoint kWorkStart = SurfacePdopWork::TimePoint{} + 1000s;
constexpr std::uint32_t kAnnounced[] = {1};

SurfacePdopWork::From gateway_a() {
  // Claims every surface node but 9; announced module 1 only.
  return {3, "gw-a", kAnnounced, [](canopen::NodeId node) { return node != 9; }};
}

v1::PdopNodes nodes_list() {
  v1::PdopNodes nodes;
  const auto add = [&](std::uint32_t module, std::uint32_t node, bool whole) {
    v1::PdopNodes::Node& n = *nodes.add_nodes();
    n.set_module_id(module);
    n.set_surface_node(node);
    n.set_whole(whole);
  };
  add(1, 5, true);   // relayed whole
  add(1, 6, false);  // fragments cross as frames
  add(1, 9, true);   // outside the gateway's claims
  add(1, 40, true);  // no pdop node id
  add(2, 7, true);   // a module it did not announce
  return nodes;
}

// A master's one-frame RPDOP packet (a plain RPDO) to surface node `node`, RPDO 1.
std::vector<can::Frame> master_packet(canopen::NodeId node) {
  const std::vector<std::uint8_t> bytes = {1, 2, 3, 4, 5};
  return canopen::pdop::fragment(canopen::pdop::rpdo_base(1), node, bytes);
}

TEST(SurfacePdopWork, TheNodeListDecidesOwnersAndHowPacketsCross) {
  SurfacePdopWork work;
  work.on_nodes(gateway_a(), nodes_list());
  EXPECT_EQ(work.counters().malformed, 3u);
  EXPECT_TRUE(work.relay().relayed(5));
  EXPECT_FALSE(work.fragments_as_frames(5));
  EXPECT_TRUE(work.fragments_as_frames(6));
  EXPECT_FALSE(work.relay().relayed(6));
  EXPECT_FALSE(work.relay().relayed(9));
  // Node 6's frames are not the relay's: they cross as frames, in bus order.
  for (const can::Frame& f : master_packet(6)) EXPECT_FALSE(work.on_bus_frame(f, kWorkStart));
}

TEST(SurfacePdopWork, AMastersPacketGoesToItsOwnersGatewayAndItsOutcomeAnswersTheMaster) {
  SurfacePdopWork work;
  work.on_nodes(gateway_a(), nodes_list());
  for (const can::Frame& f : master_packet(5)) EXPECT_TRUE(work.on_bus_frame(f, kWorkStart));
  std::vector<SurfacePdopWork::GatewayId> asked;
  SurfacePdopWork::Output& out = work.flush([&](SurfacePdopWork::GatewayId g) {
    asked.push_back(g);
    return true;
  });
  EXPECT_EQ(asked, std::vector<SurfacePdopWork::GatewayId>{3});
  ASSERT_EQ(out.payloads.size(), 1u);
  EXPECT_EQ(out.payloads[0].first, 3u);
  v1::Payload sent;
  ASSERT_TRUE(sent.ParseFromString(out.payloads[0].second));
  ASSERT_EQ(sent.pdop_packets().packets_size(), 1);
  const v1::PdopPacket& p = sent.pdop_packets().packets(0);
  EXPECT_EQ(p.module_id(), 1u);
  EXPECT_EQ(p.surface_node(), 5u);
  EXPECT_EQ(p.pdo(), 1u);
  EXPECT_EQ(p.data(), std::string("\x01\x02\x03\x04\x05"));
  EXPECT_EQ(work.counters().rpdop_forwarded, 1u);
  // The node took it: counted complete, and the master gets its final acknowledgement.
  v1::PdopReports reports;
  v1::RpdopOutcome& outcome = *reports.add_outcomes();
  outcome.set_request_id(p.request_id());
  outcome.set_surface_node(5);
  outcome.set_rpdo(1);
  outcome.set_result(v1::RpdopOutcome::COMPLETE);
  v1::PdopDiscard& discard = *reports.add_discards();
  discard.set_surface_node(5);
  work.on_reports(gateway_a(), reports);
  EXPECT_EQ(work.counters().rpdop_complete, 1u);
  EXPECT_EQ(work.counters().discards, 1u);
  const SurfacePdopWork::Output& acked =
      work.flush([](SurfacePdopWork::GatewayId) { return true; });
  EXPECT_TRUE(acked.payloads.empty());
  ASSERT_FALSE(acked.frames.empty());
  EXPECT_EQ(acked.frames.back().id, canopen::pdop::ack_cob_id(5));  // its final acknowledgement
}

TEST(SurfacePdopWork, APacketWhoseGatewayIsDownIsAnsweredAtOnce) {
  SurfacePdopWork work;
  work.on_nodes(gateway_a(), nodes_list());
  for (const can::Frame& f : master_packet(5)) work.on_bus_frame(f, kWorkStart);
  const SurfacePdopWork::Output& out = work.flush([](SurfacePdopWork::GatewayId) { return false; });
  EXPECT_TRUE(out.payloads.empty());
  EXPECT_EQ(work.counters().rpdop_failed, 1u);
  EXPECT_EQ(work.counters().rpdop_forwarded, 0u);
  ASSERT_FALSE(out.frames.empty());    // the master's answer: 0x82, no room
  EXPECT_FALSE(work.next_deadline());  // nothing left waiting for an outcome
}

TEST(SurfacePdopWork, TpdopPacketsAreJudgedAndCounted) {
  SurfacePdopWork work;
  v1::PdopPacket packet;
  packet.set_module_id(1);
  packet.set_surface_node(5);
  packet.set_pdo(2);
  packet.set_data(std::string(20, '\x5A'));
  ASSERT_EQ(work.on_packet(gateway_a(), packet).verdict, PdopPacketToBus::Verdict::to_bus);
  packet.set_probable_repeat(true);
  work.delivered(gateway_a(), packet);
  EXPECT_EQ(work.counters().packets, 1u);
  EXPECT_EQ(work.counters().packet_bytes, 20u);
  EXPECT_EQ(work.counters().probable_repeats, 1u);
  packet.set_module_id(2);  // not announced
  EXPECT_EQ(work.on_packet(gateway_a(), packet).verdict, PdopPacketToBus::Verdict::cannot_be_put);
  EXPECT_EQ(work.counters().malformed, 1u);
  packet.set_module_id(1);
  packet.set_surface_node(9);  // outside the claims: the caller's to count, per gateway
  EXPECT_EQ(work.on_packet(gateway_a(), packet).verdict, PdopPacketToBus::Verdict::not_its_own);
  EXPECT_EQ(work.counters().malformed, 1u);
}

}  // namespace
}  // namespace canbridge::bridge
