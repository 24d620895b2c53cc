// The little-endian helpers and the fpga node-id command codec built on them.
#include "canopen/little_endian.hpp"

#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "canopen/nmt_node_id.hpp"

namespace canbridge::canopen {
namespace {

TEST(LittleEndian, LoadsAndStoresLeastSignificantByteFirst) {
  const std::array<std::uint8_t, 9> bytes{0x78, 0x56, 0x34, 0x12, 0xEF, 0xCD, 0xAB, 0x90, 0xFF};
  EXPECT_EQ(load_le(std::span(bytes).first(2)), 0x5678u);
  EXPECT_EQ(load_le32(bytes), 0x12345678u);        // only the first 4 bytes
  EXPECT_EQ(load_le(bytes), 0x90ABCDEF12345678u);  // only the first 8 bytes
  EXPECT_EQ(load_le({}), 0u);
  std::vector<std::uint8_t> out(3, 0xEE);
  store_le(0x11223344, out);
  EXPECT_EQ(out, (std::vector<std::uint8_t>{0x44, 0x33, 0x22}));
}

TEST(NmtNodeIdCommand, RoundTripsTheDocumentedFrames) {
  const nmt_node_id::ChangeNodeId change{5, 9};
  EXPECT_EQ(nmt_node_id::encode(change), can::Frame::standard(0x000, {0xE0, 0x05, 0x09}));
  EXPECT_EQ(nmt_node_id::decode_change(nmt_node_id::encode(change)), change);
  // docs/nmt-node-id.md: cansend vcan1 000#E1091234ABCD gives id 9 to serial 0xCDAB3412.
  const nmt_node_id::SetNodeIdBySerial by_serial{9, 0xCDAB3412};
  EXPECT_EQ(nmt_node_id::encode(by_serial),
            can::Frame::standard(0x000, {0xE1, 0x09, 0x12, 0x34, 0xAB, 0xCD}));
  EXPECT_EQ(nmt_node_id::decode_by_serial(nmt_node_id::encode(by_serial)), by_serial);
}

TEST(NmtNodeIdCommand, MalformedFramesDecodeToNothing) {
  EXPECT_FALSE(nmt_node_id::decode_change(can::Frame::standard(0x000, {0xE0, 0x05})));
  EXPECT_FALSE(nmt_node_id::decode_change(can::Frame::standard(0x000, {0xE0, 0x05, 0x20})));
  EXPECT_FALSE(nmt_node_id::decode_change(can::Frame::standard(0x000, {0xE0, 0x00, 0x05})));
  EXPECT_FALSE(nmt_node_id::decode_change(can::Frame::standard(0x001, {0xE0, 0x05, 0x09})));
  EXPECT_FALSE(nmt_node_id::decode_by_serial(can::Frame::standard(0x000, {0xE1, 0x09, 1, 2, 3})));
  EXPECT_FALSE(
      nmt_node_id::decode_by_serial(can::Frame::standard(0x000, {0xE1, 0x00, 1, 2, 3, 4})));
}

}  // namespace
}  // namespace canbridge::canopen
