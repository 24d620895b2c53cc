// The delivery class of every kind of frame, the sender whose order a frame keeps, and the rules
// the lane table must keep (bridge/delivery_class.hpp, bridge/delivery_lanes.hpp).
#include "bridge/delivery_class.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "bridge/delivery_lanes.hpp"
#include "can/frame.hpp"

namespace canbridge::bridge {
namespace {

using C = DeliveryClass;

can::Frame std_frame(std::uint32_t id, std::initializer_list<std::uint8_t> bytes = {0x11}) {
  return can::Frame::standard(id, bytes);
}

struct Case {
  std::string what;
  can::Frame frame;
  C plain;      // no pdop fragments at this node
  C fragments;  // the node's PDO Packets cross as frames
};

TEST(DeliveryClass, EveryFrameHasOneClass) {
  const std::vector<Case> cases = {
      {"NMT", std_frame(0x000, {0x01, 0x00}), C::reliable, C::reliable},
      {"SYNC", std_frame(0x080, {}), C::process_data, C::process_data},
      {"EMCY node 1", std_frame(0x081, {0, 0x10}), C::reliable, C::reliable},
      {"EMCY node 127", std_frame(0x0FF, {0, 0x10}), C::reliable, C::reliable},
      {"TIME", std_frame(0x100, {1, 2, 3, 4, 5, 6}), C::process_data, C::process_data},
      {"TPDO1 node 1", std_frame(0x181), C::process_data, C::ordered_fragment},
      {"TPDOP fragment t=1 c=1", std_frame(0x1E1), C::process_data, C::ordered_fragment},
      {"RPDO1 node 1", std_frame(0x201), C::process_data, C::ordered_fragment},
      {"RPDOP fragment c=1", std_frame(0x221), C::process_data, C::ordered_fragment},
      {"TPDO4 node 127", std_frame(0x4FF), C::process_data, C::ordered_fragment},
      {"RPDO4 node 127", std_frame(0x57F), C::process_data, C::ordered_fragment},
      {"SDO response", std_frame(0x581, {0x43}), C::reliable, C::reliable},
      {"SDO request", std_frame(0x601, {0x40}), C::reliable, C::reliable},
      {"PDOP acknowledgement", std_frame(0x681, {0x80, 0, 0, 0, 0}), C::reliable, C::reliable},
      {"boot-up", std_frame(0x705, {0x00}), C::reliable, C::reliable},
      {"heartbeat operational", std_frame(0x705, {0x05}), C::latest_value, C::latest_value},
      {"heartbeat pre-operational", std_frame(0x77F, {0x7F}), C::latest_value, C::latest_value},
      {"heartbeat of two bytes", std_frame(0x705, {0x05, 0x00}), C::reliable, C::reliable},
      {"node guarding request (RTR)", can::Frame::make(0x705, can::FrameFlags::remote, {}),
       C::reliable, C::reliable},
      {"TPDO request (RTR)", can::Frame::make(0x181, can::FrameFlags::remote, {}), C::reliable,
       C::reliable},
      {"LSS master", std_frame(0x7E5, {0x04, 0x01}), C::reliable, C::reliable},
      {"LSS slave", std_frame(0x7E4, {0x44}), C::reliable, C::reliable},
      {"extended with a PDO's base", can::Frame::make(0x181u << 18, can::FrameFlags::extended, {1}),
       C::reliable, C::reliable},
  };
  for (const Case& c : cases) {
    for (const bool conflate : {false, true}) {
      // `conflate_pdos` decides what the process lane does, never the class.
      EXPECT_EQ(classify(c.frame, {.conflate_pdos = conflate}), c.plain) << c.what;
      EXPECT_EQ(classify(c.frame, {.conflate_pdos = conflate, .pdop_fragments = true}), c.fragments)
          << c.what;
    }
  }
}

TEST(DeliveryClass, TheSenderIsTheNodeForWhatANodeSendsAndTheMasterForTheRest) {
  struct SenderCase {
    std::uint32_t id;
    canopen::NodeId sender;
  };
  const std::vector<SenderCase> cases = {
      {0x000, kMasterSender},
      {0x080, kMasterSender},  // NMT, SYNC
      {0x081, 1},
      {0x0FF, 127},  // EMCY
      {0x100, kMasterSender},
      {0x105, kMasterSender},  // TIME and its unused range
      {0x185, 5},
      {0x205, kMasterSender},  // TPDO1 / RPDO1
      {0x285, 5},
      {0x305, kMasterSender},  // TPDO2 / RPDO2
      {0x385, 5},
      {0x405, kMasterSender},  // TPDO3 / RPDO3
      {0x485, 5},
      {0x505, kMasterSender},  // TPDO4 / RPDO4
      {0x585, 5},
      {0x5FF, 127},  // SDO responses
      {0x605, kMasterSender},
      {0x67F, kMasterSender},  // SDO requests
      {0x685, kMasterSender},  // PDOP acknowledgement: not predefined
      {0x701, 1},
      {0x77F, 127},  // heartbeats and boot-ups
      {0x7E4, kMasterSender},
      {0x7E5, kMasterSender},  // LSS
  };
  for (const SenderCase& c : cases) {
    EXPECT_EQ(bus_sender(std_frame(c.id)), c.sender) << std::hex << "0x" << c.id;
  }
  EXPECT_EQ(bus_sender(can::Frame::make(0x705, can::FrameFlags::remote, {})), kMasterSender)
      << "a node guarding request is the master's";
  EXPECT_EQ(bus_sender(can::Frame::make(0x00000085, can::FrameFlags::extended, {1})),
            kMasterSender);
}

TEST(DeliveryLanes, WhatIsResentIsRefusedWhenFullNeverDroppedAndNeverConflated) {
  for (std::size_t i = 0; i < kFrameLanes; ++i) {
    const Lane& lane = kLanes[i];
    if (lane.reliable) {
      EXPECT_EQ(lane.overflow, backbone::Overflow::refuse) << lane.name;
      EXPECT_EQ(lane.conflation, Conflation::never) << lane.name;
    }
  }
  EXPECT_TRUE(lane_of(DeliveryClass::reliable).reliable);
  EXPECT_EQ(lane_of(DeliveryClass::reliable).fifo, FifoPer::sender);
  // Latest values are never resent: a replayed heartbeat would show a node alive that may not be.
  EXPECT_FALSE(lane_of(DeliveryClass::latest_value).reliable);
  EXPECT_EQ(lane_of(DeliveryClass::latest_value).conflation, Conflation::always);
  EXPECT_EQ(lane_of(DeliveryClass::process_data).conflation, Conflation::module_option);
  // Fragments k and k + 2 share a COB-ID: conflating them would corrupt the packet.
  EXPECT_EQ(lane_of(DeliveryClass::ordered_fragment).conflation, Conflation::never);
  EXPECT_EQ(lane_of(DeliveryClass::ordered_fragment).fifo, FifoPer::packet);
  EXPECT_EQ(lane_of(DeliveryClass::node_event).rank, Rank::ahead_of_frames);
  EXPECT_EQ(LaneBounds{}.*lane_of(DeliveryClass::node_event).bound, 1024u);
}

}  // namespace
}  // namespace canbridge::bridge
