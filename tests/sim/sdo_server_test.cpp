// The CiA 301 SDO server, frame by frame with an injected clock: expedited, segmented and block
// transfers, their error paths, and the CRC they use.
#include "sim/sdo_server.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <stdexcept>
#include <string_view>

#include "canopen/crc16.hpp"
#include "canopen/sdo_client.hpp"

namespace canbridge::sim {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Frames = std::vector<Frame>;
using Bytes = std::vector<std::uint8_t>;
using TimePoint = SdoServer::TimePoint;
using canopen::SdoAbort;

constexpr canopen::NodeId kNode = 5;
const TimePoint t0 = TimePoint{} + 1h;

constexpr std::uint16_t kDeviceType = 0x1000;
constexpr std::uint16_t kDeviceName = 0x1008;
constexpr std::uint16_t kHeartbeat = 0x1017;
constexpr std::uint16_t kIdentity = 0x1018;
constexpr std::uint16_t kDomain = 0x2000;
constexpr std::uint16_t kWriteOnly = 0x2001;
constexpr std::uint16_t kByte = 0x2002;
constexpr std::uint16_t kEmptyDomain = 0x2003;
constexpr std::uint16_t kSmallDomain = 0x2004;
constexpr std::string_view kName = "canbridge simulated node";  // 24 bytes: segmented

Bytes pattern(std::size_t size, std::uint8_t seed = 0) {
  Bytes b(size);
  for (std::size_t i = 0; i < size; ++i) b[i] = static_cast<std::uint8_t>(i * 7 + seed);
  return b;
}

Bytes bytes_of(std::string_view s) {
  return {s.begin(), s.end()};
}

std::uint8_t lo(std::uint32_t v, int byte) {
  return static_cast<std::uint8_t>(v >> (8 * byte));
}

// An 8-byte frame: command byte, multiplexer, then a 32-bit little-endian value.
Frame frame(std::uint32_t id, std::uint8_t command, std::uint16_t index, std::uint8_t sub,
            std::uint32_t value = 0) {
  return Frame::standard(id, {command, lo(index, 0), lo(index, 1), sub, lo(value, 0), lo(value, 1),
                              lo(value, 2), lo(value, 3)});
}
Frame request(std::uint8_t command, std::uint16_t index = 0, std::uint8_t sub = 0,
              std::uint32_t value = 0) {
  return frame(0x600 + kNode, command, index, sub, value);
}
Frame response(std::uint8_t command, std::uint16_t index = 0, std::uint8_t sub = 0,
               std::uint32_t value = 0) {
  return frame(0x580 + kNode, command, index, sub, value);
}
Frame abort_response(std::uint16_t index, std::uint8_t sub, SdoAbort code) {
  return response(0x80, index, sub, static_cast<std::uint32_t>(code));
}
// Command byte then up to 7 data bytes, zero-padded to 8.
Frame segment(std::uint32_t id, std::uint8_t command, std::span<const std::uint8_t> data) {
  Frame f = Frame::standard(id, {command, 0, 0, 0, 0, 0, 0, 0});
  std::copy(data.begin(), data.end(), f.data.begin() + 1);
  return f;
}
// Block commands with two parameter bytes after the command (ackseq/blksize, CRC).
Frame request2(std::uint8_t command, std::uint8_t b1, std::uint8_t b2) {
  return Frame::standard(0x600 + kNode, {command, b1, b2, 0, 0, 0, 0, 0});
}
Frame response2(std::uint8_t command, std::uint8_t b1, std::uint8_t b2) {
  return Frame::standard(0x580 + kNode, {command, b1, b2, 0, 0, 0, 0, 0});
}

std::span<const std::uint8_t> chunk(const Bytes& data, std::size_t at, std::size_t max = 7) {
  return std::span<const std::uint8_t>(data).subspan(at, std::min(max, data.size() - at));
}

void fill(ObjectDictionary& od) {
  od.add_unsigned(kDeviceType, 0, Access::constant, 0x00000191, 4);
  od.add(kDeviceName, 0, Access::ro, DataType::visible_string, bytes_of(kName));
  od.add_unsigned(kHeartbeat, 0, Access::rw, 1000, 2);
  od.add_unsigned(kIdentity, 0, Access::constant, 4, 1);
  od.add_unsigned(kIdentity, 1, Access::ro, 0x000001A2, 4);
  od.add(kDomain, 0, Access::rw, DataType::domain, pattern(1000));
  od.add_unsigned(kWriteOnly, 0, Access::wo, 0, 4);
  od.add_unsigned(kByte, 0, Access::rw, 0x11, 1);
  od.add(kEmptyDomain, 0, Access::rw, DataType::domain, {});
  od.add(kSmallDomain, 0, Access::rw, DataType::domain, {0xAA, 0xBB, 0xCC});
}

SdoServerOptions options(SdoLevel level = SdoLevel::block, std::uint8_t block_size = 127) {
  SdoServerOptions o;
  o.node_id = kNode;
  o.level = level;
  o.timeout = 500ms;
  o.max_block_size = block_size;
  return o;
}

class SdoServerTest : public ::testing::Test {
 protected:
  explicit SdoServerTest(SdoServerOptions o = options()) : server(od, o) {}

  Frames send(const Frame& f, TimePoint now = t0) {
    Frames out;
    server.on_request(f, now, out);
    return out;
  }
  Frame send_one(const Frame& f, TimePoint now = t0) {
    const Frames out = send(f, now);
    EXPECT_EQ(out.size(), 1u) << "after " << can::to_string(f);
    return out.empty() ? Frame{} : out.front();
  }
  Bytes value(std::uint16_t index, std::uint8_t sub = 0) const {
    const OdEntry* entry = od.find(index, sub);
    return entry == nullptr ? Bytes{} : entry->value;
  }

  // A client's segmented upload after the initiate response; checks every segment's toggle, n
  // and c bits and returns the data.
  Bytes upload_segments(std::size_t size) {
    Bytes data;
    bool toggle = false;
    for (bool last = false; !last;) {
      const Frame f = send_one(request(toggle ? 0x70 : 0x60));
      EXPECT_EQ(f.data[0] & 0xF0, toggle ? 0x10 : 0x00) << can::to_string(f);
      const std::size_t length = 7 - ((f.data[0] >> 1) & 0x07);
      last = (f.data[0] & 0x01) != 0;
      data.insert(data.end(), f.data.begin() + 1, f.data.begin() + 1 + length);
      toggle = !toggle;
      if (data.size() > size) break;
    }
    EXPECT_FALSE(server.busy());
    return data;
  }

  // A client's segmented download after the initiate response.
  void download_segments(const Bytes& data) {
    bool toggle = false;
    std::size_t at = 0;
    do {
      const auto part = chunk(data, at);
      at += part.size();
      const bool last = at == data.size();
      const auto command =
          static_cast<std::uint8_t>((toggle ? 0x10 : 0) | (7 - part.size()) << 1 | (last ? 1 : 0));
      EXPECT_EQ(send_one(segment(0x600 + kNode, command, part)), response(toggle ? 0x30 : 0x20));
      toggle = !toggle;
    } while (at < data.size());
  }

  // Sends segments of `data` from byte `at` as one sub-block of up to `block_size` segments;
  // returns the frames the server answered with and advances nothing (the ack decides).
  Frames block_download_sub_block(const Bytes& data, std::size_t at, std::uint8_t block_size) {
    Frames answers;
    for (std::uint8_t seqno = 1; seqno <= block_size && at < data.size(); ++seqno) {
      const auto part = chunk(data, at);
      at += part.size();
      const bool last = at == data.size();
      const Frames out = send(segment(0x600 + kNode, (last ? 0x80 : 0) | seqno, part));
      answers.insert(answers.end(), out.begin(), out.end());
    }
    return answers;
  }

  // A complete block download with every sub-block acknowledged in full; `crc` is what the
  // client puts in the end command. Returns the server's answer to that end command.
  Frame block_download(std::uint16_t index, const Bytes& data, std::uint16_t crc,
                       std::uint8_t block_size = 127) {
    EXPECT_EQ(send_one(request(0xC6, index, 0, static_cast<std::uint32_t>(data.size()))),
              response(0xA4, index, 0, block_size));
    std::size_t at = 0;
    while (at < data.size()) {
      const Frames acks = block_download_sub_block(data, at, block_size);
      const std::size_t sent = std::min<std::size_t>(block_size, (data.size() - at + 6) / 7);
      EXPECT_EQ(acks, Frames{response2(0xA2, static_cast<std::uint8_t>(sent), block_size)});
      at = std::min(data.size(), at + sent * 7);
    }
    const auto unused = static_cast<std::uint8_t>((7 - data.size() % 7) % 7);
    return send_one(
        request2(static_cast<std::uint8_t>(0xC1 | unused << 2), lo(crc, 0), lo(crc, 1)));
  }

  // A complete block upload with the given client block size and every sub-block acknowledged in
  // full; checks the size, c bits, n and CRC and returns the data.
  Bytes block_upload(std::uint16_t index, std::uint8_t block_size) {
    const Frame initiate = send_one(request(0xA4, index, 0, block_size));
    EXPECT_EQ(initiate.data[0], 0xC6);
    const std::uint32_t size = initiate.data[4] | initiate.data[5] << 8 | initiate.data[6] << 16 |
                               static_cast<std::uint32_t>(initiate.data[7]) << 24;
    Bytes data;
    Frames segments = send(request(0xA3));
    for (;;) {
      EXPECT_FALSE(segments.empty());
      if (segments.empty()) return data;
      for (std::size_t i = 0; i < segments.size(); ++i) {
        EXPECT_EQ(static_cast<std::size_t>(segments[i].data[0] & 0x7F), i + 1);
        data.insert(data.end(), segments[i].data.begin() + 1, segments[i].data.end());
      }
      const bool last = (segments.back().data[0] & 0x80) != 0;
      const Frames answer =
          send(request2(0xA2, static_cast<std::uint8_t>(segments.size()), block_size));
      if (last) {
        EXPECT_EQ(answer.size(), 1u);
        if (answer.size() != 1) return data;
        const Frame& end = answer.front();
        EXPECT_EQ(end.data[0] & 0xE3, 0xC1);
        data.resize(data.size() - ((end.data[0] >> 2) & 0x07));
        EXPECT_EQ(end.data[1] | end.data[2] << 8, canopen::crc16_xmodem(data));
        EXPECT_TRUE(send(request(0xA1)).empty());
        break;
      }
      segments = answer;
    }
    EXPECT_EQ(data.size(), size);
    EXPECT_FALSE(server.busy());
    return data;
  }

  ObjectDictionary od = [] {
    ObjectDictionary d;
    fill(d);
    return d;
  }();
  SdoServer server;
};

class SmallBlockTest : public SdoServerTest {
 protected:
  SmallBlockTest() : SdoServerTest(options(SdoLevel::block, 4)) {}
};
class ExpeditedOnlyTest : public SdoServerTest {
 protected:
  ExpeditedOnlyTest() : SdoServerTest(options(SdoLevel::expedited)) {}
};
class SegmentedOnlyTest : public SdoServerTest {
 protected:
  SegmentedOnlyTest() : SdoServerTest(options(SdoLevel::segmented)) {}
};

// --- CRC ----------------------------------------------------------------------------------------

TEST(Crc16Xmodem, CheckValueAndIncrementalUse) {
  const Bytes check = bytes_of("123456789");
  EXPECT_EQ(canopen::crc16_xmodem(check), 0x31C3);
  const auto first = canopen::crc16_xmodem(std::span(check).first(4));
  EXPECT_EQ(canopen::crc16_xmodem(std::span(check).subspan(4), first), 0x31C3);
  EXPECT_EQ(canopen::crc16_xmodem({}), 0);
}

// --- construction -------------------------------------------------------------------------------

TEST(SdoServerConstruction, InvalidOptionsThrow) {
  ObjectDictionary od;
  auto with = [](auto change) {
    SdoServerOptions o = options();
    change(o);
    return o;
  };
  auto make = [&](const SdoServerOptions& o) { SdoServer server(od, o); };
  EXPECT_THROW(make(with([](auto& o) { o.node_id = 0; })), std::invalid_argument);
  EXPECT_THROW(make(with([](auto& o) { o.node_id = 128; })), std::invalid_argument);
  EXPECT_THROW(make(with([](auto& o) { o.max_block_size = 0; })), std::invalid_argument);
  EXPECT_THROW(make(with([](auto& o) { o.max_block_size = 128; })), std::invalid_argument);
  EXPECT_THROW(make(with([](auto& o) { o.timeout = 0ms; })), std::invalid_argument);
  EXPECT_NO_THROW(make(options()));
}

// --- expedited ----------------------------------------------------------------------------------

TEST_F(SdoServerTest, ExpeditedUploadIndicatesTheSize) {
  EXPECT_EQ(send(request(0x40, kDeviceType)), Frames{response(0x43, kDeviceType, 0, 0x191)});
  EXPECT_EQ(send(request(0x40, kByte)), Frames{response(0x4F, kByte, 0, 0x11)});
  EXPECT_EQ(send(request(0x40, kSmallDomain)), Frames{response(0x47, kSmallDomain, 0, 0xCCBBAA)});
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().transfers_ok, 3u);
}

TEST_F(SdoServerTest, ExpeditedDownloadWritesTheDictionary) {
  EXPECT_EQ(send(request(0x2B, kHeartbeat, 0, 250)), Frames{response(0x60, kHeartbeat)});
  EXPECT_EQ(value(kHeartbeat), (Bytes{250, 0}));
  EXPECT_EQ(send(request(0x2F, kByte, 0, 0x42)), Frames{response(0x60, kByte)});
  EXPECT_EQ(value(kByte), Bytes{0x42});
  EXPECT_EQ(server.counters().transfers_ok, 2u);
}

TEST_F(SdoServerTest, ExpeditedDownloadWithoutSizeTakesTheEntrySize) {
  // e=1, s=0: 4 bytes on the wire, the UNSIGNED16 takes 2 of them.
  EXPECT_EQ(send(request(0x22, kHeartbeat, 0, 0xDEAD0102)), Frames{response(0x60, kHeartbeat)});
  EXPECT_EQ(value(kHeartbeat), (Bytes{0x02, 0x01}));
  // A domain has no size of its own: all 4 bytes count.
  EXPECT_EQ(send(request(0x22, kSmallDomain, 0, 0x04030201)), Frames{response(0x60, kSmallDomain)});
  EXPECT_EQ(value(kSmallDomain), (Bytes{1, 2, 3, 4}));
}

TEST_F(SdoServerTest, DictionaryErrorsBecomeAborts) {
  EXPECT_EQ(send(request(0x40, 0x6000)), Frames{abort_response(0x6000, 0, SdoAbort::no_object)});
  EXPECT_EQ(send(request(0x40, kIdentity, 9)),
            Frames{abort_response(kIdentity, 9, SdoAbort::no_sub_index)});
  EXPECT_EQ(send(request(0x40, kWriteOnly)),
            Frames{abort_response(kWriteOnly, 0, SdoAbort::read_write_only)});
  EXPECT_EQ(send(request(0x23, kDeviceType, 0, 1)),
            Frames{abort_response(kDeviceType, 0, SdoAbort::write_read_only)});
  EXPECT_EQ(send(request(0x23, kHeartbeat, 0, 1)),
            Frames{abort_response(kHeartbeat, 0, SdoAbort::length_too_high)});
  EXPECT_EQ(send(request(0x2F, kHeartbeat, 0, 1)),
            Frames{abort_response(kHeartbeat, 0, SdoAbort::length_too_low)});
  EXPECT_EQ(server.counters().aborts_sent, 6u);
  EXPECT_EQ(server.counters().transfers_ok, 0u);
  EXPECT_EQ(value(kHeartbeat), (Bytes{0xE8, 0x03}));
}

TEST_F(SdoServerTest, DownloadChecksThatNeedNoDataFailAtInitiate) {
  // Segmented initiates with size indicated.
  EXPECT_EQ(send(request(0x21, kHeartbeat, 0, 10)),
            Frames{abort_response(kHeartbeat, 0, SdoAbort::length_too_high)});
  EXPECT_EQ(send(request(0x21, 0x1020, 0, 10)),
            Frames{abort_response(0x1020, 0, SdoAbort::no_object)});
  EXPECT_EQ(send(request(0x21, kDeviceName, 0, 10)),
            Frames{abort_response(kDeviceName, 0, SdoAbort::write_read_only)});
  EXPECT_EQ(send(request(0x21, kDomain, 0, kMaxVariableBytes + 1)),
            Frames{abort_response(kDomain, 0, SdoAbort::out_of_memory)});
  od.add(0x2005, 0, Access::rw, DataType::unsigned64, Bytes(8));
  EXPECT_EQ(send(request(0x21, 0x2005, 0, 5)),
            Frames{abort_response(0x2005, 0, SdoAbort::length_too_low)});
  // Block initiates too.
  EXPECT_EQ(send(request(0xC6, kHeartbeat, 0, 10)),
            Frames{abort_response(kHeartbeat, 0, SdoAbort::length_too_high)});
  EXPECT_EQ(send(request(0xC6, kIdentity, 7, 10)),
            Frames{abort_response(kIdentity, 7, SdoAbort::no_sub_index)});
  EXPECT_FALSE(server.busy());
}

TEST_F(SdoServerTest, WriteGuardVerdictAbortsACompletedDownload) {
  od.set_write_guard([](const OdEntry& entry, std::span<const std::uint8_t>) -> std::error_code {
    if (entry.index == kDomain) return SdoAbort::device_state;
    return {};
  });
  EXPECT_EQ(send(request(0x21, kDomain, 0, 10)), Frames{response(0x60, kDomain)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7, 1))), Frames{response(0x20)});
  EXPECT_EQ(send(segment(0x605, 0x10 | 4 << 1 | 1, pattern(3, 2))),
            Frames{abort_response(kDomain, 0, SdoAbort::device_state)});
  EXPECT_EQ(value(kDomain), pattern(1000));
  EXPECT_FALSE(server.busy());
}

// --- segmented ----------------------------------------------------------------------------------

TEST_F(SdoServerTest, SegmentedUploadOfAString) {
  EXPECT_EQ(send(request(0x40, kDeviceName)), Frames{response(0x41, kDeviceName, 0, 24)});
  EXPECT_TRUE(server.busy());
  // 24 bytes: 7 + 7 + 7 + 3, the last with n = 4 and c.
  EXPECT_EQ(send(request(0x60)), Frames{segment(0x585, 0x00, bytes_of(kName.substr(0, 7)))});
  EXPECT_EQ(send(request(0x70)), Frames{segment(0x585, 0x10, bytes_of(kName.substr(7, 7)))});
  EXPECT_EQ(send(request(0x60)), Frames{segment(0x585, 0x00, bytes_of(kName.substr(14, 7)))});
  EXPECT_EQ(send(request(0x70)), Frames{segment(0x585, 0x19, bytes_of(kName.substr(21)))});
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, SegmentedUploadOfA1000ByteDomain) {
  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  EXPECT_EQ(upload_segments(1000), pattern(1000));
}

TEST_F(SdoServerTest, EmptyValueUploadsAsOneEmptySegment) {
  EXPECT_EQ(send(request(0x40, kEmptyDomain)), Frames{response(0x41, kEmptyDomain, 0, 0)});
  EXPECT_EQ(send(request(0x60)), Frames{segment(0x585, 0x0F, {})});
  EXPECT_FALSE(server.busy());
}

TEST_F(SdoServerTest, SegmentedDownloadWritesOnceWhenComplete) {
  int writes = 0;
  od.set_write_listener([&](const OdEntry&) { ++writes; });
  const Bytes data = pattern(1000, 3);
  EXPECT_EQ(send(request(0x21, kDomain, 0, 1000)), Frames{response(0x60, kDomain)});
  download_segments(data);
  EXPECT_EQ(writes, 1);
  EXPECT_EQ(value(kDomain), data);
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, SegmentedDownloadWithoutSizeIndication) {
  // A variable-length entry may change size: 9 bytes into the 3-byte domain.
  EXPECT_EQ(send(request(0x20, kSmallDomain)), Frames{response(0x60, kSmallDomain)});
  download_segments(pattern(9));
  EXPECT_EQ(value(kSmallDomain), pattern(9));
  // A number without size indication: the entry's size bounds the data.
  EXPECT_EQ(send(request(0x20, kHeartbeat)), Frames{response(0x60, kHeartbeat)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))),
            Frames{abort_response(kHeartbeat, 0, SdoAbort::length_too_high)});
}

TEST_F(SdoServerTest, SegmentedDownloadLengthMustMatchTheIndicatedSize) {
  EXPECT_EQ(send(request(0x21, kDomain, 0, 10)), Frames{response(0x60, kDomain)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))), Frames{response(0x20)});
  EXPECT_EQ(send(segment(0x605, 0x10 | 5 << 1 | 1, pattern(2))),
            Frames{abort_response(kDomain, 0, SdoAbort::length_mismatch)});
  // More than indicated is refused as soon as it arrives.
  EXPECT_EQ(send(request(0x21, kDomain, 0, 10)), Frames{response(0x60, kDomain)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))), Frames{response(0x20)});
  EXPECT_EQ(send(segment(0x605, 0x10, pattern(7))),
            Frames{abort_response(kDomain, 0, SdoAbort::length_mismatch)});
  EXPECT_EQ(value(kDomain), pattern(1000));
}

TEST_F(SdoServerTest, WrongToggleAbortsSegmentedTransfers) {
  EXPECT_EQ(send(request(0x21, kDomain, 0, 20)), Frames{response(0x60, kDomain)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))), Frames{response(0x20)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))),
            Frames{abort_response(kDomain, 0, SdoAbort::toggle_bit)});
  EXPECT_FALSE(server.busy());

  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  EXPECT_EQ(send(request(0x70)), Frames{abort_response(kDomain, 0, SdoAbort::toggle_bit)});
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().aborts_sent, 2u);
}

// --- block download -----------------------------------------------------------------------------

TEST_F(SdoServerTest, BlockDownloadOf1000BytesWithCrc) {
  const Bytes data = pattern(1000, 9);
  // 143 segments: a sub-block of 127 and one of 16; n = 1.
  EXPECT_EQ(block_download(kDomain, data, canopen::crc16_xmodem(data)), response(0xA1));
  EXPECT_EQ(value(kDomain), data);
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, BlockDownloadWithWrongCrcAborts) {
  const Bytes data = pattern(1000, 9);
  const auto bad = static_cast<std::uint16_t>(canopen::crc16_xmodem(data) ^ 0x0100);
  EXPECT_EQ(block_download(kDomain, data, bad), abort_response(kDomain, 0, SdoAbort::crc_error));
  EXPECT_EQ(value(kDomain), pattern(1000));
  EXPECT_FALSE(server.busy());
}

TEST_F(SdoServerTest, BlockDownloadWithoutClientCrcIgnoresTheField) {
  // cc = 0, s = 1.
  EXPECT_EQ(send(request(0xC2, kSmallDomain, 0, 9)), Frames{response(0xA4, kSmallDomain, 0, 127)});
  EXPECT_TRUE(send(segment(0x605, 0x01, pattern(7))).empty());
  EXPECT_EQ(send(segment(0x605, 0x82, chunk(pattern(9), 7))), Frames{response2(0xA2, 2, 127)});
  EXPECT_EQ(send(request2(0xC1 | 5 << 2, 0x12, 0x34)), Frames{response(0xA1)});
  EXPECT_EQ(value(kSmallDomain), pattern(9));
}

TEST_F(SdoServerTest, BlockDownloadSizeMismatchAtTheEnd) {
  EXPECT_EQ(send(request(0xC6, kSmallDomain, 0, 8)), Frames{response(0xA4, kSmallDomain, 0, 127)});
  EXPECT_TRUE(send(segment(0x605, 0x01, pattern(7))).empty());
  EXPECT_EQ(send(segment(0x605, 0x82, pattern(7))), Frames{response2(0xA2, 2, 127)});
  // n = 5 leaves 9 bytes, not the 8 indicated.
  EXPECT_EQ(send(request2(0xC1 | 5 << 2, 0, 0)),
            Frames{abort_response(kSmallDomain, 0, SdoAbort::length_mismatch)});
}

TEST_F(SdoServerTest, BlockDownloadSequenceNumberErrors) {
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 100)), Frames{response(0xA4, kDomain, 0, 127)});
  EXPECT_EQ(send(segment(0x605, 0x00, pattern(7))),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_sequence)});
  EXPECT_FALSE(server.busy());
}

TEST_F(SmallBlockTest, BlockDownloadSeqnoAboveBlockSizeAborts) {
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 100)), Frames{response(0xA4, kDomain, 0, 4)});
  EXPECT_EQ(send(segment(0x605, 0x05, pattern(7))),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_sequence)});
}

TEST_F(SmallBlockTest, BlockDownloadInSubBlocksOfTheGrantedSize) {
  const Bytes data = pattern(100, 4);
  EXPECT_EQ(block_download(kDomain, data, canopen::crc16_xmodem(data), 4), response(0xA1));
  EXPECT_EQ(value(kDomain), data);
}

TEST_F(SmallBlockTest, OutOfOrderSegmentIsRepeatedAfterTheAck) {
  const Bytes data = pattern(40, 6);  // 6 segments
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 40)), Frames{response(0xA4, kDomain, 0, 4)});
  EXPECT_TRUE(send(segment(0x605, 0x01, chunk(data, 0))).empty());
  EXPECT_TRUE(send(segment(0x605, 0x02, chunk(data, 7))).empty());
  // Segment 3 is lost; 4 ends the sub-block and the ack names 2, the last in order.
  EXPECT_EQ(send(segment(0x605, 0x04, chunk(data, 21))), Frames{response2(0xA2, 2, 4)});
  EXPECT_TRUE(server.busy());
  // The client repeats from segment 3, numbered from 1 in the new sub-block.
  EXPECT_TRUE(send(segment(0x605, 0x01, chunk(data, 14))).empty());
  EXPECT_TRUE(send(segment(0x605, 0x02, chunk(data, 21))).empty());
  // A duplicate is ignored.
  EXPECT_TRUE(send(segment(0x605, 0x02, chunk(data, 21))).empty());
  EXPECT_TRUE(send(segment(0x605, 0x03, chunk(data, 28))).empty());
  EXPECT_EQ(send(segment(0x605, 0x84, chunk(data, 35))), Frames{response2(0xA2, 4, 4)});
  const auto crc = canopen::crc16_xmodem(data);
  EXPECT_EQ(send(request2(0xC1 | 2 << 2, lo(crc, 0), lo(crc, 1))), Frames{response(0xA1)});
  EXPECT_EQ(value(kDomain), data);
}

TEST_F(SmallBlockTest, OutOfOrderLastSegmentEndsTheSubBlock) {
  const Bytes data = pattern(20, 2);  // 3 segments
  EXPECT_EQ(send(request(0xC6, kSmallDomain, 0, 20)), Frames{response(0xA4, kSmallDomain, 0, 4)});
  EXPECT_TRUE(send(segment(0x605, 0x01, chunk(data, 0))).empty());
  EXPECT_EQ(send(segment(0x605, 0x83, chunk(data, 14))), Frames{response2(0xA2, 1, 4)});
  EXPECT_TRUE(send(segment(0x605, 0x01, chunk(data, 7))).empty());
  EXPECT_EQ(send(segment(0x605, 0x82, chunk(data, 14))), Frames{response2(0xA2, 2, 4)});
  const auto crc = canopen::crc16_xmodem(data);
  EXPECT_EQ(send(request2(0xC1 | 1 << 2, lo(crc, 0), lo(crc, 1))), Frames{response(0xA1)});
  EXPECT_EQ(value(kSmallDomain), data);
}

TEST_F(SdoServerTest, BlockDownloadBeyondTheIndicatedSizeAborts) {
  EXPECT_EQ(send(request(0xC6, kSmallDomain, 0, 7)), Frames{response(0xA4, kSmallDomain, 0, 127)});
  EXPECT_TRUE(send(segment(0x605, 0x01, pattern(7))).empty());
  EXPECT_EQ(send(segment(0x605, 0x02, pattern(7))),
            Frames{abort_response(kSmallDomain, 0, SdoAbort::length_mismatch)});
}

TEST_F(SdoServerTest, MegabyteDomainRoundTripsThroughBlockTransfers) {
  const Bytes data = pattern(1024 * 1024, 5);
  EXPECT_EQ(block_download(kDomain, data, canopen::crc16_xmodem(data)), response(0xA1));
  EXPECT_EQ(value(kDomain), data);
  EXPECT_EQ(block_upload(kDomain, 127), data);
  EXPECT_EQ(server.counters().transfers_ok, 2u);
}

// --- block upload -------------------------------------------------------------------------------

TEST_F(SdoServerTest, BlockUploadOf1000Bytes) {
  EXPECT_EQ(block_upload(kDomain, 127), pattern(1000));
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, BlockUploadInSmallSubBlocksOfAString) {
  EXPECT_EQ(block_upload(kDeviceName, 2), bytes_of(kName));
}

TEST_F(SdoServerTest, BlockUploadRetransmitsAfterAPartialAck) {
  const Bytes data = pattern(1000);
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 10)), Frames{response(0xC6, kDomain, 0, 1000)});
  Frames first = send(request(0xA3));
  ASSERT_EQ(first.size(), 10u);
  EXPECT_EQ(first[5], segment(0x585, 0x06, chunk(data, 35)));
  // Only 6 arrived: the next sub-block starts with segment 7's data, numbered 1.
  Frames second = send(request2(0xA2, 6, 3));
  ASSERT_EQ(second.size(), 3u);
  EXPECT_EQ(second[0], segment(0x585, 0x01, chunk(data, 42)));
  EXPECT_EQ(second[2], segment(0x585, 0x03, chunk(data, 56)));
  // Acknowledging more than was sent is a sequence error.
  EXPECT_EQ(send(request2(0xA2, 4, 3)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_sequence)});
  EXPECT_FALSE(server.busy());
}

TEST_F(SdoServerTest, BlockUploadEndCarriesUnusedBytesAndCrc) {
  const Bytes data = pattern(9);
  od.set_bytes(kSmallDomain, 0, data);
  EXPECT_EQ(send(request(0xA4, kSmallDomain, 0, 127)), Frames{response(0xC6, kSmallDomain, 0, 9)});
  EXPECT_EQ(send(request(0xA3)),
            (Frames{segment(0x585, 0x01, chunk(data, 0)), segment(0x585, 0x82, chunk(data, 7))}));
  const auto crc = canopen::crc16_xmodem(data);
  EXPECT_EQ(send(request2(0xA2, 2, 127)), Frames{response2(0xC1 | 5 << 2, lo(crc, 0), lo(crc, 1))});
  EXPECT_TRUE(server.busy());
  EXPECT_TRUE(send(request(0xA1)).empty());
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, BlockUploadOfAnEmptyValue) {
  EXPECT_EQ(send(request(0xA4, kEmptyDomain, 0, 127)), Frames{response(0xC6, kEmptyDomain, 0, 0)});
  EXPECT_EQ(send(request(0xA3)), Frames{segment(0x585, 0x81, {})});
  EXPECT_EQ(send(request2(0xA2, 1, 127)), Frames{response2(0xC1 | 7 << 2, 0, 0)});
  EXPECT_TRUE(send(request(0xA1)).empty());
  EXPECT_EQ(server.counters().transfers_ok, 1u);
}

TEST_F(SdoServerTest, InvalidBlockSizesAbort) {
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 0)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_block_size)});
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 128)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_block_size)});
  // ... and in the client's acknowledgement.
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 127)), Frames{response(0xC6, kDomain, 0, 1000)});
  EXPECT_EQ(send(request(0xA3)).size(), 127u);
  EXPECT_EQ(send(request2(0xA2, 127, 0)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_block_size)});
  EXPECT_FALSE(server.busy());
}

TEST_F(SdoServerTest, ProtocolSwitchThresholdFallsBackToSdoUpload) {
  // pst 30 >= 24 bytes: a segmented upload instead.
  EXPECT_EQ(send(request(0xA4, kDeviceName, 0, 30 << 8 | 127)),
            Frames{response(0x41, kDeviceName, 0, 24)});
  EXPECT_EQ(upload_segments(24), bytes_of(kName));
  // pst 4 and 4 bytes: expedited.
  EXPECT_EQ(send(request(0xA4, kDeviceType, 0, 4 << 8 | 127)),
            Frames{response(0x43, kDeviceType, 0, 0x191)});
  EXPECT_FALSE(server.busy());
  // pst 23 < 24 bytes, or pst 0: block.
  EXPECT_EQ(send(request(0xA4, kDeviceName, 0, 23 << 8 | 127)),
            Frames{response(0xC6, kDeviceName, 0, 24)});
  server.reset();
  EXPECT_EQ(send(request(0xA4, kDeviceType, 0, 127)), Frames{response(0xC6, kDeviceType, 0, 4)});
  EXPECT_EQ(server.counters().transfers_ok, 2u);
}

TEST_F(SdoServerTest, UnexpectedRequestInABlockUploadAborts) {
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 127)), Frames{response(0xC6, kDomain, 0, 1000)});
  // An acknowledgement before the start command.
  EXPECT_EQ(send(request2(0xA2, 0, 127)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
}

// --- transfers and their end --------------------------------------------------------------------

TEST_F(SdoServerTest, NewRequestDuringATransferAbortsItAndIsDropped) {
  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  EXPECT_EQ(send(request(0x60)).size(), 1u);
  // The open transfer is aborted under its own multiplexer; the new request is not served.
  EXPECT_EQ(send(request(0x40, kDeviceType)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
  EXPECT_FALSE(server.busy());
  // The client's retry is.
  EXPECT_EQ(send(request(0x40, kDeviceType)), Frames{response(0x43, kDeviceType, 0, 0x191)});
}

TEST_F(SdoServerTest, ClientAbortEndsTheTransferSilently) {
  EXPECT_EQ(send(request(0x21, kDomain, 0, 100)), Frames{response(0x60, kDomain)});
  EXPECT_TRUE(send(request(0x80, kDomain, 0, 0x08000000)).empty());
  EXPECT_FALSE(server.busy());
  // Inside a block download sub-block, 0x80 is the abort too.
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 100)), Frames{response(0xA4, kDomain, 0, 127)});
  EXPECT_TRUE(send(segment(0x605, 0x01, pattern(7))).empty());
  EXPECT_TRUE(send(request(0x80, kDomain, 0, 0x05040000)).empty());
  EXPECT_FALSE(server.busy());
  // An abort with nothing open changes nothing.
  EXPECT_TRUE(send(request(0x80, kDomain, 0, 0x05040000)).empty());
  EXPECT_EQ(server.counters().aborts_received, 3u);
  EXPECT_EQ(server.counters().aborts_sent, 0u);
  EXPECT_EQ(value(kDomain), pattern(1000));
}

TEST_F(SdoServerTest, IdleTransferTimesOut) {
  EXPECT_EQ(server.next_deadline(), TimePoint::max());
  EXPECT_EQ(send(request(0x40, kDomain), t0), Frames{response(0x41, kDomain, 0, 1000)});
  EXPECT_EQ(server.next_deadline(), t0 + 500ms);
  // Activity restarts the timer.
  EXPECT_EQ(send(request(0x60), t0 + 400ms).size(), 1u);
  EXPECT_EQ(server.next_deadline(), t0 + 900ms);
  Frames out;
  server.on_tick(t0 + 899ms, out);
  EXPECT_TRUE(out.empty());
  server.on_tick(t0 + 900ms, out);
  EXPECT_EQ(out, Frames{abort_response(kDomain, 0, SdoAbort::timeout)});
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.next_deadline(), TimePoint::max());
  EXPECT_EQ(server.counters().timeouts, 1u);
  EXPECT_EQ(server.counters().aborts_sent, 1u);
  out.clear();
  server.on_tick(t0 + 1h, out);
  EXPECT_TRUE(out.empty());
}

TEST_F(SdoServerTest, BlockDownloadTimesOutWaitingForSegments) {
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 100), t0), Frames{response(0xA4, kDomain, 0, 127)});
  Frames out;
  server.on_tick(t0 + 500ms, out);
  EXPECT_EQ(out, Frames{abort_response(kDomain, 0, SdoAbort::timeout)});
}

TEST_F(SdoServerTest, UnknownCommandsAndStraySegmentsAbortWithoutAddress) {
  EXPECT_EQ(send(request(0xE0, kDomain)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0x60)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0x00)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0xA3)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request2(0xC1, 0, 0)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
}

TEST_F(SdoServerTest, FramesThatAreNotSdoAreIgnored) {
  EXPECT_TRUE(send(Frame::standard(0x605, {0x40, 0x00, 0x10, 0x00})).empty());
  Frame remote = request(0x40, kDeviceType);
  remote.flags = can::FrameFlags::remote;
  EXPECT_TRUE(send(remote).empty());
  EXPECT_EQ(server.counters().aborts_sent, 0u);
}

TEST_F(SdoServerTest, ResetDropsTheTransferSilently) {
  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  server.reset();
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.next_deadline(), TimePoint::max());
  EXPECT_EQ(send(request(0x60)), Frames{abort_response(0, 0, SdoAbort::invalid_command)});
}

TEST_F(SdoServerTest, NodeIdChangeMovesTheResponsesAndResets) {
  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  server.set_node_id(9);
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(send(request(0x40, kDeviceType)), Frames{frame(0x589, 0x43, kDeviceType, 0, 0x191)});
  EXPECT_THROW(server.set_node_id(0), std::invalid_argument);
  EXPECT_THROW(server.set_node_id(128), std::invalid_argument);
}

// --- levels -------------------------------------------------------------------------------------

TEST_F(ExpeditedOnlyTest, RefusesSegmentedAndBlockTransfers) {
  EXPECT_EQ(send(request(0x40, kDeviceType)), Frames{response(0x43, kDeviceType, 0, 0x191)});
  EXPECT_EQ(send(request(0x2F, kByte, 0, 7)), Frames{response(0x60, kByte)});
  EXPECT_EQ(send(request(0x40, kDeviceName)),
            Frames{abort_response(kDeviceName, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0x21, kDomain, 0, 10)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 10)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 127)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
  EXPECT_FALSE(server.busy());
}

TEST_F(SegmentedOnlyTest, RefusesBlockTransfers) {
  EXPECT_EQ(send(request(0x40, kDomain)), Frames{response(0x41, kDomain, 0, 1000)});
  EXPECT_EQ(upload_segments(1000), pattern(1000));
  EXPECT_EQ(send(request(0xC6, kDomain, 0, 10)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
  EXPECT_EQ(send(request(0xA4, kDomain, 0, 127)),
            Frames{abort_response(kDomain, 0, SdoAbort::invalid_command)});
}

// --- the repository's SDO client ----------------------------------------------------------------

// The client is expedited-only, so this covers expedited transfers and its refusal of a segmented
// upload, whose abort must free the server.
TEST_F(SdoServerTest, WorksWithTheRepositorySdoClient) {
  using canopen::SdoClientTransaction;
  auto run = [&](SdoClientTransaction t) {
    Frames answers = send(t.start(t0), t0);
    EXPECT_EQ(answers.size(), 1u);
    canopen::SdoStep step = t.on_frame(answers.at(0), t0);
    if (step.send) {
      EXPECT_TRUE(send(*step.send, t0).empty());
    }
    EXPECT_TRUE(step.result.has_value());
    return step.result.value_or(canopen::SdoResult{});
  };
  const Bytes heartbeat{0x2C, 0x01};
  EXPECT_TRUE(run(SdoClientTransaction::download(kNode, {kHeartbeat, 0}, heartbeat, 100ms)).ok());
  EXPECT_EQ(value(kHeartbeat), heartbeat);
  EXPECT_EQ(run(SdoClientTransaction::upload(kNode, {kHeartbeat, 0}, 100ms)).data, heartbeat);
  EXPECT_EQ(run(SdoClientTransaction::upload(kNode, {0x6000, 0}, 100ms)).error,
            make_error_code(SdoAbort::no_object));
  EXPECT_EQ(run(SdoClientTransaction::upload(kNode, {kDeviceName, 0}, 100ms)).error,
            make_error_code(SdoAbort::unsupported_access));
  EXPECT_FALSE(server.busy());
  EXPECT_EQ(server.counters().aborts_received, 1u);
}

}  // namespace
}  // namespace canbridge::sim
