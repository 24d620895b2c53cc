// The CANopen decoder behind `canbridge dump`: each service's frames named with their fields,
// the SDO phases that only state can tell apart, PDO Packets on pdop buses, and the filters.
#include "canopen/frame_decoder.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "canopen/pdop.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::canopen {
namespace {

using can::Frame;
using ::testing::HasSubstr;

DecodedFrame decode_one(const Frame& f, BusLayout layout = BusLayout::cia301) {
  FrameDecoder decoder;
  decoder.set_layout(1, layout);
  return decoder.decode(f, 1);
}

TEST(FrameDecoder, Nmt) {
  auto d = decode_one(Frame::standard(0x000, {0x01, 0x05}));
  EXPECT_EQ(d.kind, FrameKind::nmt);
  EXPECT_EQ(d.text, "NMT start node 5");
  EXPECT_EQ(d.node, NodeId{5});
  EXPECT_EQ(decode_one(Frame::standard(0x000, {0x82, 0x00})).text,
            "NMT reset communication all nodes");
  EXPECT_FALSE(decode_one(Frame::standard(0x000, {0x82, 0x00})).node.has_value());
  EXPECT_EQ(decode_one(Frame::standard(0x000, {0x80, 0x7F})).text,
            "NMT enter pre-operational node 127");
  EXPECT_EQ(decode_one(Frame::standard(0x000, {0xE0, 0x05, 0x09})).text,
            "NMT change node id 5 -> 9");
  EXPECT_EQ(decode_one(Frame::standard(0x000, {0xE1, 0x09, 0x12, 0x34, 0xAB, 0xCD})).text,
            "NMT set node id 9 on serial number 0xCDAB3412");
  EXPECT_EQ(decode_one(Frame::standard(0x000, {0x01})).text, "NMT start (1 bytes, not 2)");
}

TEST(FrameDecoder, SyncAndTime) {
  EXPECT_EQ(decode_one(Frame::standard(0x080, {})).text, "SYNC");
  EXPECT_EQ(decode_one(Frame::standard(0x080, {})).kind, FrameKind::sync);
  EXPECT_EQ(decode_one(Frame::standard(0x080, {7})).text, "SYNC counter 7");
  // 12:34:56.789 = 45296789 ms = 0x02B32C95; 2024-01-01 is 14610 days after 1984-01-01.
  const auto t = decode_one(Frame::standard(0x100, {0x95, 0x2C, 0xB3, 0x02, 0x12, 0x39}));
  EXPECT_EQ(t.kind, FrameKind::time);
  EXPECT_EQ(t.text, "TIME 2024-01-01 12:34:56.789");
}

TEST(FrameDecoder, Emcy) {
  const auto d = decode_one(Frame::standard(0x085, {0x10, 0x81, 0x11, 1, 2, 3, 4, 5}));
  EXPECT_EQ(d.kind, FrameKind::emcy);
  EXPECT_EQ(d.node, NodeId{5});
  EXPECT_EQ(d.text,
            "EMCY node 5 code 8110 (CAN overrun (objects lost)) register 11 data 01 02 03 04 05");
  EXPECT_THAT(decode_one(Frame::standard(0x085, {0, 0, 0, 0, 0, 0, 0, 0})).text,
              HasSubstr("code 0000 (error reset or no error)"));
  EXPECT_THAT(decode_one(Frame::standard(0x085, {0x34, 0x42, 0x08, 0, 0, 0, 0, 0})).text,
              HasSubstr("code 4234 (device temperature)"));
  EXPECT_THAT(
      decode_one(Frame::standard(0x085, {0x09, 0xF0, 0x80, 0, 0, 0, 0, 0}), BusLayout::qd).text,
      HasSubstr("code F009 (state change of subsystems 0 3)"));
}

TEST(FrameDecoder, HeartbeatBootUpAndGuarding) {
  EXPECT_EQ(decode_one(Frame::standard(0x705, {0x05})).text, "heartbeat node 5 operational");
  EXPECT_EQ(decode_one(Frame::standard(0x705, {0x7F})).text, "heartbeat node 5 pre-operational");
  EXPECT_EQ(decode_one(Frame::standard(0x705, {0x00})).text, "boot-up node 5");
  EXPECT_EQ(decode_one(Frame::standard(0x705, {0x84})).text, "heartbeat node 5 stopped toggle 1");
  EXPECT_EQ(decode_one(Frame::make(0x705, can::FrameFlags::remote, {})).text,
            "node guarding request node 5");
  EXPECT_EQ(decode_one(Frame::standard(0x705, {0x05})).kind, FrameKind::heartbeat);
}

TEST(FrameDecoder, LoaderBootUpOnlyOnQdBuses) {
  const auto qd = decode_one(Frame::standard(0x725, {0x00}), BusLayout::qd);
  EXPECT_EQ(qd.kind, FrameKind::loader);
  EXPECT_EQ(qd.node, NodeId{5});
  EXPECT_EQ(qd.text, "loader boot-up node 5");
  // On a CiA 301 bus the same frame is node 37's boot-up.
  const auto cia = decode_one(Frame::standard(0x725, {0x00}));
  EXPECT_EQ(cia.kind, FrameKind::heartbeat);
  EXPECT_EQ(cia.text, "boot-up node 37");
}

TEST(FrameDecoder, Pdos) {
  const auto t = decode_one(Frame::standard(0x185, {1, 2}));
  EXPECT_EQ(t.kind, FrameKind::pdo);
  EXPECT_EQ(t.text, "TPDO1 node 5: 01 02");
  EXPECT_EQ(decode_one(Frame::standard(0x505, {})).text, "RPDO4 node 5: (no data)");
  EXPECT_EQ(decode_one(Frame::make(0x285, can::FrameFlags::remote, {})).text,
            "TPDO2 node 5 remote request");
  // qd: slots of the PDO and SDO ranges are further TPDOs (docs/sim-nodes.md).
  EXPECT_EQ(decode_one(Frame::standard(0x1A5, {9}), BusLayout::qd).text, "TPDO2 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x225, {9}), BusLayout::qd).text, "TPDO5 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x205, {9}), BusLayout::qd).text, "RPDO1 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x565, {9}), BusLayout::qd).text, "TPDO28 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x5A5, {9}), BusLayout::qd).text, "TPDO29 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x665, {9}), BusLayout::qd).text, "TPDO34 node 5: 09");
  EXPECT_EQ(decode_one(Frame::standard(0x1A5, {9})).text, "TPDO1 node 37: 09");
}

TEST(FrameDecoder, SdoExpeditedAndAbort) {
  FrameDecoder d;
  const sdo::Multiplexer mux{0x1018, 1};
  auto r = d.decode(sdo::upload_request(5, mux));
  EXPECT_EQ(r.kind, FrameKind::sdo);
  EXPECT_EQ(r.node, NodeId{5});
  EXPECT_EQ(r.text, "SDO request node 5: upload 1018:01");
  const std::uint8_t value[] = {0x78, 0x56, 0x34, 0x12};
  EXPECT_EQ(d.decode(sdo::upload_response(5, mux, value)).text,
            "SDO response node 5: upload 1018:01 = 78 56 34 12");
  const std::uint8_t one[] = {0x2A};
  EXPECT_EQ(d.decode(sdo::download_request(5, {0x2000, 0}, one)).text,
            "SDO request node 5: download 2000:00 = 2A");
  EXPECT_EQ(d.decode(sdo::download_response(5, {0x2000, 0})).text,
            "SDO response node 5: download 2000:00 OK");
  EXPECT_EQ(d.decode(sdo::abort_response(5, {0x6000, 0}, SdoAbort::no_object)).text,
            "SDO response node 5: abort 6000:00 object does not exist in the object dictionary "
            "(0x06020000)");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0x40, 0x18})).text,
            "SDO request node 5: (2 bytes: not an SDO frame)");
}

TEST(FrameDecoder, SdoSegmentedUpload) {
  FrameDecoder d;
  d.decode(sdo::upload_request(5, {0x1008, 0}));
  EXPECT_EQ(d.decode(sdo::segmented_upload_response(5, {0x1008, 0}, 10)).text,
            "SDO response node 5: upload 1008:00 segmented, size 10");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0x60, 0, 0, 0, 0, 0, 0, 0})).text,
            "SDO request node 5: upload segment request t=0 (1008:00)");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0x00, 'c', 'a', 'n', 'b', 'r', 'i', 'd'})).text,
            "SDO response node 5: upload segment t=0 (1008:00) 7 bytes: 63 61 6E 62 72 69 64");
  // n = 4 unused bytes, c = 1: 3 bytes, the last segment.
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0x19, 'g', 'e', '!', 0, 0, 0, 0})).text,
            "SDO response node 5: upload segment t=1 (1008:00) 3 bytes: 67 65 21 (last)");
}

TEST(FrameDecoder, SdoBlockDownloadSegmentsNeedTheTransfersState) {
  FrameDecoder d;
  // Initiate with size and CRC: ccs 6, cc=1, s=1.
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0xC6, 0x50, 0x1F, 0x01, 0x0E, 0, 0, 0})).text,
            "SDO request node 5: block download 1F50:01 initiate, size 14, CRC");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0xA4, 0x50, 0x1F, 0x01, 0x7F, 0, 0, 0})).text,
            "SDO response node 5: block download 1F50:01 accepted, blksize 127, CRC");
  // Segment 1 (0x01) would be a download segment by its command specifier, segment 2 (0x82,
  // last) an abort-like 0x80 pattern: only the phase makes them block segments.
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0x01, 1, 2, 3, 4, 5, 6, 7})).text,
            "SDO request node 5: block download segment 1 7 bytes: 01 02 03 04 05 06 07");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0x82, 8, 9, 10, 11, 12, 13, 14})).text,
            "SDO request node 5: block download segment 2 7 bytes: 08 09 0A 0B 0C 0D 0E (last)");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0xA2, 0x02, 0x7F, 0, 0, 0, 0, 0})).text,
            "SDO response node 5: block download ack seq 2, blksize 127 (1F50:01)");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0xC1, 0x34, 0x12, 0, 0, 0, 0, 0})).text,
            "SDO request node 5: block download end (1F50:01), 0 unused bytes, CRC 1234");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0xA1, 0, 0, 0, 0, 0, 0, 0})).text,
            "SDO response node 5: block download end OK (1F50:01)");
  // After the transfer, 0x01 is a download segment again.
  EXPECT_THAT(d.decode(Frame::standard(0x605, {0x01, 0, 0, 0, 0, 0, 0, 0})).text,
              HasSubstr("download segment t=0"));
}

TEST(FrameDecoder, SdoBlockDownloadResendAfterALowAck) {
  FrameDecoder d;
  d.decode(Frame::standard(0x605, {0xC6, 0x50, 0x1F, 0x01, 0x0E, 0, 0, 0}));
  d.decode(Frame::standard(0x585, {0xA4, 0x50, 0x1F, 0x01, 0x7F, 0, 0, 0}));
  d.decode(Frame::standard(0x605, {0x01, 1, 2, 3, 4, 5, 6, 7}));
  d.decode(Frame::standard(0x605, {0x82, 8, 9, 10, 11, 12, 13, 14}));
  d.decode(Frame::standard(0x585, {0xA2, 0x01, 0x7F, 0, 0, 0, 0, 0}));  // segment 2 was lost
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0x81, 8, 9, 10, 11, 12, 13, 14})).text,
            "SDO request node 5: block download segment 1 7 bytes: 08 09 0A 0B 0C 0D 0E (last)");
}

TEST(FrameDecoder, SdoBlockUpload) {
  FrameDecoder d;
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0xA4, 0x08, 0x10, 0x00, 0x7F, 0x00, 0, 0})).text,
            "SDO request node 5: block upload 1008:00 initiate, blksize 127, pst 0, CRC");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0xC6, 0x08, 0x10, 0x00, 0x09, 0, 0, 0})).text,
            "SDO response node 5: block upload 1008:00, size 9, CRC");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0xA3, 0, 0, 0, 0, 0, 0, 0})).text,
            "SDO request node 5: block upload start (1008:00)");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0x01, 1, 2, 3, 4, 5, 6, 7})).text,
            "SDO response node 5: block upload segment 1 7 bytes: 01 02 03 04 05 06 07");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0x82, 8, 9, 0, 0, 0, 0, 0})).text,
            "SDO response node 5: block upload segment 2 7 bytes: 08 09 00 00 00 00 00 (last)");
  EXPECT_EQ(d.decode(Frame::standard(0x605, {0xA2, 0x02, 0x7F, 0, 0, 0, 0, 0})).text,
            "SDO request node 5: block upload ack seq 2, blksize 127 (1008:00)");
  EXPECT_EQ(d.decode(Frame::standard(0x585, {0xD5, 0xCD, 0xAB, 0, 0, 0, 0, 0})).text,
            "SDO response node 5: block upload end (1008:00), 5 unused bytes, CRC ABCD");
}

TEST(FrameDecoder, SdoStateIsPerModuleAndNode) {
  FrameDecoder d;
  d.decode(Frame::standard(0x605, {0xC6, 0x50, 0x1F, 0x01, 0x0E, 0, 0, 0}), 1);
  d.decode(Frame::standard(0x585, {0xA4, 0x50, 0x1F, 0x01, 0x7F, 0, 0, 0}), 1);
  // Node 5 of module 2 runs no block transfer: its 0x01 frame is a download segment.
  EXPECT_THAT(d.decode(Frame::standard(0x605, {0x01, 0, 0, 0, 0, 0, 0, 0}), 2).text,
              HasSubstr("download segment t=0"));
  EXPECT_THAT(d.decode(Frame::standard(0x605, {0x01, 0, 0, 0, 0, 0, 0, 0}), 1).text,
              HasSubstr("block download segment 1"));
  // An abort ends the block phase.
  d.decode(sdo::abort_request(5, {0x1F50, 1}, SdoAbort::general), 1);
  EXPECT_THAT(d.decode(Frame::standard(0x605, {0x01, 0, 0, 0, 0, 0, 0, 0}), 1).text,
              HasSubstr("download segment t=0"));
}

TEST(FrameDecoder, PdoPacketFragmentsAndWholePackets) {
  FrameDecoder d;
  d.set_layout(1, BusLayout::pdop);
  std::vector<std::uint8_t> packet(20);
  for (std::size_t i = 0; i < packet.size(); ++i) packet[i] = static_cast<std::uint8_t>(i);
  const auto fragments = pdop::fragment(pdop::tpdo_base(1), 5, packet);
  ASSERT_EQ(fragments.size(), 3u);
  const auto first = d.decode(fragments[0], 1);
  EXPECT_EQ(first.kind, FrameKind::pdop);
  EXPECT_EQ(first.node, NodeId{5});
  EXPECT_EQ(first.text, "PDOP TPDO1 node 5 t=0 c=1: 00 01 02 03 04 05 06 07");
  EXPECT_EQ(d.decode(fragments[1], 1).text, "PDOP TPDO1 node 5 t=1 c=1: 08 09 0A 0B 0C 0D 0E 0F");
  EXPECT_EQ(d.decode(fragments[2], 1).text,
            "PDOP TPDO1 node 5 t=0 c=0: 10 11 12 13 -> packet of 20 bytes: 00 01 02 03 04 05 06 "
            "07 08 09 0A 0B 0C 0D 0E 0F ...");
  // A plain one-frame packet is just its fragment.
  EXPECT_EQ(d.decode(Frame::standard(0x185, {1}), 1).text, "PDOP TPDO1 node 5 t=0 c=0: 01");
  // The same ids on a CiA 301 module are PDOs of other nodes.
  EXPECT_EQ(d.decode(fragments[0], 2).text, "TPDO1 node 37: 00 01 02 03 04 05 06 07");
}

TEST(FrameDecoder, PdoPacketErrors) {
  FrameDecoder d;
  d.set_layout(1, BusLayout::pdop);
  // t=1 first: the first fragment is missing.
  EXPECT_THAT(d.decode(Frame::standard(0x1C5, {0, 1, 2, 3, 4, 5, 6, 7}), 1).text,
              HasSubstr("(no first fragment, dropped)"));
  d.decode(Frame::standard(0x1A5, {0, 1, 2, 3, 4, 5, 6, 7}), 1);  // t=0 c=1
  EXPECT_THAT(d.decode(Frame::standard(0x1A5, {0, 1, 2, 3, 4, 5, 6, 7}), 1).text,
              HasSubstr("(toggle error: 8 bytes dropped)"));
  EXPECT_THAT(d.decode(Frame::standard(0x1A5, {1, 2}), 1).text,
              HasSubstr("(short fragment, packet dropped)"));
  EXPECT_EQ(d.decode(pdop::abort_frame(pdop::rpdo_base(2), 5), 1).text,
            "PDOP RPDO2 node 5 t=0 c=0 sender abort");
}

TEST(FrameDecoder, PdopAcknowledgements) {
  FrameDecoder d;
  d.set_layout(1, BusLayout::pdop);
  const auto ack = d.decode(pdop::encode_ack(5, {2, pdop::AckStatus::complete, 3, 4}), 1);
  EXPECT_EQ(ack.kind, FrameKind::pdop);
  EXPECT_EQ(ack.text, "PDOP ack node 5 RPDO2 complete, received 3, credit 4");
  EXPECT_EQ(d.decode(pdop::encode_ack(5, {1, pdop::AckStatus::toggle_error, 1, 4}), 1).text,
            "PDOP ack node 5 RPDO1 abort: toggle error, received 1, credit 4");
  EXPECT_EQ(d.decode(pdop::ack_request(5), 1).text, "PDOP ack request node 5");
}

TEST(FrameDecoder, Lss) {
  EXPECT_EQ(decode_one(Frame::standard(0x7E5, {0x04, 0x01, 0, 0, 0, 0, 0, 0})).text,
            "LSS master switch state global configuration");
  EXPECT_EQ(decode_one(Frame::standard(0x7E5, {0x11, 0x07, 0, 0, 0, 0, 0, 0})).text,
            "LSS master configure node id 7");
  EXPECT_EQ(decode_one(Frame::standard(0x7E5, {0x40, 0x78, 0x56, 0x34, 0x12, 0, 0, 0})).text,
            "LSS master switch state selective vendor 0x12345678");
  EXPECT_EQ(decode_one(Frame::standard(0x7E4, {0x5D, 0x01, 0x00, 0x00, 0x00, 0, 0, 0})).text,
            "LSS slave inquire serial = 0x00000001");
  EXPECT_EQ(decode_one(Frame::standard(0x7E4, {0x5D})).kind, FrameKind::lss);
}

TEST(FrameDecoder, UnknownFrames) {
  EXPECT_EQ(decode_one(Frame::standard(0x101, {1})).text, "unknown COB-ID 0x101: 01");
  EXPECT_EQ(decode_one(Frame::standard(0x101, {1})).kind, FrameKind::unknown);
  EXPECT_EQ(decode_one(Frame::make(0x12345678, can::FrameFlags::extended, {1, 2})).text,
            "extended id 0x12345678: 01 02");
  // On a pdop bus node ids stop at 31: 0x7A5 is no heartbeat there.
  EXPECT_EQ(decode_one(Frame::standard(0x7A5, {5}), BusLayout::pdop).kind, FrameKind::unknown);
}

TEST(FrameFilter, ModuleNodeAndKinds) {
  FrameDecoder d;
  const auto hb = d.decode(Frame::standard(0x705, {0x05}), 1);
  const auto sdo = d.decode(sdo::upload_request(6, {0x1000, 0}), 1);
  FrameFilter all;
  EXPECT_TRUE(all.matches(hb, 1));
  FrameFilter by_module{1, std::nullopt, {}};
  EXPECT_TRUE(by_module.matches(hb, 1));
  EXPECT_FALSE(by_module.matches(hb, 2));
  FrameFilter by_node{std::nullopt, NodeId{5}, {}};
  EXPECT_TRUE(by_node.matches(hb, 1));
  EXPECT_FALSE(by_node.matches(sdo, 1));
  FrameFilter by_kind{std::nullopt, std::nullopt, {FrameKind::sdo, FrameKind::emcy}};
  EXPECT_FALSE(by_kind.matches(hb, 1));
  EXPECT_TRUE(by_kind.matches(sdo, 1));
}

TEST(FrameKinds, NamesRoundTrip) {
  for (const char* name : {"nmt", "sync", "time", "emcy", "heartbeat", "loader", "sdo", "pdo",
                           "pdop", "lss", "unknown"}) {
    const auto kind = parse_frame_kind(name);
    ASSERT_TRUE(kind) << name;
    EXPECT_STREQ(to_string(*kind), name);
  }
  EXPECT_FALSE(parse_frame_kind("bogus"));
}

}  // namespace
}  // namespace canbridge::canopen
