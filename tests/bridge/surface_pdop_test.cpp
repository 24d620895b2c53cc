// The surface's PDO Packet decisions (bridge/surface_pdop.hpp) on their own: a packet of an
// announced module for a claimed node goes on the bus as the fragments docs/pdop.md gives, under
// the node's TPDO COB-ID; one outside the claims is told apart from one that cannot be put on a
// bus at all; an RPDOP outcome becomes the status a master reads.
#include "bridge/surface_pdop.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

using canopen::pdop::AckStatus;
using Verdict = PdopPacketToBus::Verdict;

v1::PdopPacket packet(std::uint32_t surface_node, std::uint32_t pdo, std::size_t bytes) {
  v1::PdopPacket p;
  p.set_module_id(1);
  p.set_surface_node(surface_node);
  p.set_pdo(pdo);
  p.set_data(std::string(bytes, '\x5A'));
  return p;
}

const auto kClaimsAll = [](canopen::NodeId) { return true; };

TEST(SurfacePdop, AClaimedNodesPacketGoesOnTheBusAsItsFragments) {
  const PdopPacketToBus out = surface_pdop_packet(packet(5, 2, 20), true, kClaimsAll);
  ASSERT_EQ(out.verdict, Verdict::to_bus);
  EXPECT_EQ(out.cob_id, 0x280u + 5);
  const std::string bytes(20, '\x5A');
  const auto expected = canopen::pdop::fragment(
      0x280, 5,
      std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(bytes.data()), 20));
  ASSERT_FALSE(expected.empty());
  ASSERT_EQ(out.fragments.size(), expected.size());
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(out.fragments[i].id, expected[i].id) << i;
    EXPECT_EQ(out.fragments[i].len, expected[i].len) << i;
    EXPECT_EQ(out.fragments[i].data, expected[i].data) << i;
  }
}

TEST(SurfacePdop, ANodeOutsideTheClaimsIsNotItsOwnAndNamesTheCobId) {
  const PdopPacketToBus out =
      surface_pdop_packet(packet(7, 1, 10), true, [](canopen::NodeId node) { return node != 7; });
  EXPECT_EQ(out.verdict, Verdict::not_its_own);
  EXPECT_EQ(out.cob_id, 0x187u);
  EXPECT_TRUE(out.fragments.empty());
}

TEST(SurfacePdop, WhatNoFrameSequenceCanCarryIsRefused) {
  // A module the gateway did not announce, no such TPDO, a node out of 1..31, no bytes: never
  // asked about the claims (a not-its-own count would blame the wrong thing).
  const auto never = [](canopen::NodeId) -> bool {
    ADD_FAILURE() << "claims asked";
    return false;
  };
  EXPECT_EQ(surface_pdop_packet(packet(5, 1, 10), false, never).verdict, Verdict::cannot_be_put);
  EXPECT_EQ(surface_pdop_packet(packet(5, 5, 10), true, never).verdict, Verdict::cannot_be_put);
  EXPECT_EQ(surface_pdop_packet(packet(0, 1, 10), true, never).verdict, Verdict::cannot_be_put);
  EXPECT_EQ(surface_pdop_packet(packet(32, 1, 10), true, never).verdict, Verdict::cannot_be_put);
  EXPECT_EQ(surface_pdop_packet(packet(5, 1, 0), true, kClaimsAll).verdict, Verdict::cannot_be_put);
}

TEST(SurfacePdop, AnRpdopOutcomeIsTheStatusTheMasterReads) {
  v1::RpdopOutcome o;
  o.set_result(v1::RpdopOutcome::COMPLETE);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::complete);
  o.set_result(v1::RpdopOutcome::RECEIVER_ABORT);
  o.set_status(0x80);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::toggle_error);  // the node's own status
  o.set_status(0x100);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::out_of_memory);  // not a status byte
  o.set_status(0x42);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::out_of_memory);  // not an abort status
  o.set_result(v1::RpdopOutcome::TIMEOUT);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::timeout);
  o.set_result(v1::RpdopOutcome::REFUSED_SIZE);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::oversize);
  o.set_result(v1::RpdopOutcome::REFUSED_BUSY);
  EXPECT_EQ(rpdop_ack_status(o), AckStatus::out_of_memory);
}

}  // namespace
}  // namespace canbridge::bridge
