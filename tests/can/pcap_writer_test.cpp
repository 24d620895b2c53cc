// The pcap writer byte for byte (global header, SocketCAN records with the id in network byte
// order and its flags), and tshark reading a written capture as CAN carrying CANopen.
#include "can/pcap_writer.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "tests/support/tshark.hpp"

namespace canbridge::can {
namespace {

using ::testing::ElementsAreArray;
using ::testing::HasSubstr;

std::vector<std::uint8_t> bytes_of(const std::string& s) {
  return {s.begin(), s.end()};
}

TEST(PcapWriter, GlobalHeaderIsLittleEndianMicrosecondsSocketcan) {
  std::ostringstream out;
  PcapWriter writer(out);
  const std::vector<std::uint8_t> expected = {
      0xD4, 0xC3, 0xB2, 0xA1,              // magic
      0x02, 0x00, 0x04, 0x00,              // version 2.4
      0,    0,    0,    0,    0, 0, 0, 0,  // thiszone, sigfigs
      0xFF, 0xFF, 0x00, 0x00,              // snaplen 65535
      227,  0,    0,    0,                 // LINKTYPE_CAN_SOCKETCAN
  };
  EXPECT_THAT(bytes_of(out.str()), ElementsAreArray(expected));
}

TEST(PcapWriter, RecordOfAStandardFrame) {
  std::ostringstream out;
  PcapWriter writer(out);
  Frame f = Frame::standard(0x605, {0x40, 0x18, 0x10, 0x01});
  f.timestamp = std::chrono::microseconds(1700000000123456LL);
  writer.write(f);
  const auto all = bytes_of(out.str());
  const std::vector<std::uint8_t> record(all.begin() + 24, all.end());
  const std::vector<std::uint8_t> expected = {
      0x00, 0xF1, 0x53, 0x65,               // 1700000000 s
      0x40, 0xE2, 0x01, 0x00,               // 123456 µs
      16,   0,    0,    0,    16, 0, 0, 0,  // captured, original length
      0x00, 0x00, 0x06, 0x05,               // can_id, big-endian
      4,    0,    0,    0,                  // len, pad, res0, res1
      0x40, 0x18, 0x10, 0x01, 0,  0, 0, 0,
  };
  EXPECT_THAT(record, ElementsAreArray(expected));
}

TEST(PcapWriter, ExtendedRemoteAndErrorFlags) {
  EXPECT_THAT(socketcan_record(Frame::make(0x12345678, FrameFlags::extended, {0xAA})),
              ElementsAreArray({0x92, 0x34, 0x56, 0x78, 1, 0, 0, 0, 0xAA, 0, 0, 0, 0, 0, 0, 0}));
  Frame rtr = Frame::make(0x705, FrameFlags::remote, {});
  rtr.len = 1;
  EXPECT_THAT(socketcan_record(rtr),
              ElementsAreArray({0x40, 0x00, 0x07, 0x05, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_THAT(socketcan_record(Frame::make(0x004, FrameFlags::error, {0, 4})),
              ElementsAreArray({0x20, 0x00, 0x00, 0x04, 2, 0, 0, 0, 0, 4, 0, 0, 0, 0, 0, 0}));
}

TEST(PcapWriter, TsharkDissectsTheCaptureAsCanopen) {
  const auto file = std::filesystem::temp_directory_path() /
                    ("canbridge-pcap-" + std::to_string(::getpid()) + ".pcap");
  {
    std::ofstream out(file, std::ios::binary);
    PcapWriter writer(out);
    writer.write(Frame::standard(0x000, {0x01, 0x05}));
    writer.write(Frame::standard(0x080, {}));
    writer.write(Frame::standard(0x605, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
    writer.write(Frame::standard(0x705, {0x7F}));
    writer.write(Frame::make(0x18FF0005, FrameFlags::extended, {1}));
  }
  const std::string tshark = test::find_tshark();
  ASSERT_FALSE(tshark.empty()) << "tshark is not on PATH: run tools/install-deps.sh";
  const auto run = test::run_tshark_canopen(tshark, file.string());
  std::filesystem::remove(file);
  ASSERT_EQ(run.status, 0) << run.output;
  EXPECT_THAT(run.output, HasSubstr("Controller Area Network"));
  EXPECT_THAT(run.output, HasSubstr("Protocols in frame: can:canopen"));
  EXPECT_THAT(run.output, HasSubstr("ID: 1541 (0x605)"));
  EXPECT_THAT(run.output, HasSubstr("Start remote node"));
  EXPECT_THAT(run.output, HasSubstr("SYNC"));
  EXPECT_THAT(run.output, HasSubstr("Initiate upload request"));
  EXPECT_THAT(run.output, HasSubstr("Pre-operational"));
  EXPECT_THAT(run.output, HasSubstr("Extended Flag: True"));
}

}  // namespace
}  // namespace canbridge::can
