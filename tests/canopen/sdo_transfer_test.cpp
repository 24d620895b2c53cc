// The pure SDO client transfer, driven frame by frame against the simulated node's SDO server
// (sim::SdoServer) with an injected clock, and against hand-written server frames where the
// simulated server cannot misbehave the way a test needs.
#include "canopen/sdo_transfer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <stdexcept>

#include "canopen/crc16.hpp"
#include "sim/object_dictionary.hpp"
#include "sim/sdo_server.hpp"

namespace canbridge::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using TimePoint = SdoTransfer::TimePoint;

const TimePoint t0 = TimePoint{} + 1h;
constexpr NodeId kNode = 5;
constexpr sdo::Multiplexer kUploadObject{0x2000, 0};    // a domain holding the test's bytes
constexpr sdo::Multiplexer kDownloadObject{0x2001, 0};  // an empty writable domain
constexpr sdo::Multiplexer kReadOnlyObject{0x2002, 0};

std::vector<std::uint8_t> pattern(std::size_t size) {
  std::vector<std::uint8_t> bytes(size);
  for (std::size_t i = 0; i < size; ++i) bytes[i] = static_cast<std::uint8_t>(i * 7 + (i >> 8));
  return bytes;
}

std::uint32_t abort_code_of(const Frame& f) {
  return sdo::read_u32(f, 4);
}

// One simulated node and the wire between it and the client. Frames cross one direction at a
// time, in order; the filters may change a frame or drop it (return false) to play a bad bus.
struct Wire {
  explicit Wire(sim::SdoServerOptions options = {}) : server(od, with_node(options)) {
    od.add(kUploadObject.index, kUploadObject.sub, sim::Access::rw, sim::DataType::domain, {});
    od.add(kDownloadObject.index, kDownloadObject.sub, sim::Access::rw, sim::DataType::domain, {});
    od.add(kReadOnlyObject.index, kReadOnlyObject.sub, sim::Access::ro, sim::DataType::domain,
           pattern(20));
  }
  static sim::SdoServerOptions with_node(sim::SdoServerOptions options) {
    options.node_id = kNode;
    return options;
  }
  void set_value(const std::vector<std::uint8_t>& bytes) {
    ASSERT_TRUE(od.set_bytes(kUploadObject.index, kUploadObject.sub, bytes));
  }
  std::vector<std::uint8_t> written() const {
    return od.find(kDownloadObject.index, kDownloadObject.sub)->value;
  }

  // Runs `t` to its end (and delivers what it sent last). When nothing is on the wire, time
  // jumps to the earlier of the two deadlines.
  void run(SdoTransfer& t) {
    std::vector<Frame> to_server;
    t.start(now, to_server);
    for (int idle_rounds = 0; idle_rounds < 4;) {
      std::vector<Frame> to_client;
      for (Frame& f : to_server) {
        ++client_frames;
        client_log.push_back(f);
        if (!client_filter || client_filter(f)) server.on_request(f, now, to_client);
      }
      to_server.clear();
      for (Frame& f : to_client) {
        ++server_frames;
        server_log.push_back(f);
        if (!server_filter || server_filter(f)) t.on_frame(f, now, to_server);
      }
      if (!to_server.empty() || !to_client.empty()) continue;
      if (t.finished()) return;
      ++idle_rounds;
      now = std::min(t.deadline(), server.next_deadline());
      std::vector<Frame> from_server;
      server.on_tick(now, from_server);
      for (Frame& f : from_server) {
        server_log.push_back(f);
        t.on_frame(f, now, to_server);
      }
      t.on_timeout(now, to_server);
    }
    FAIL() << "the transfer neither ended nor timed out";
  }

  sim::ObjectDictionary od;
  sim::SdoServer server;
  TimePoint now = t0;
  std::function<bool(Frame&)> client_filter;  // client -> server
  std::function<bool(Frame&)> server_filter;  // server -> client
  std::size_t client_frames = 0;
  std::size_t server_frames = 0;
  std::vector<Frame> client_log;
  std::vector<Frame> server_log;
};

SdoTransferOptions plain() {
  return {};
}

// --- plain (expedited and segmented) transfers against the simulated server --------------------

class PlainTransfer : public ::testing::TestWithParam<std::size_t> {};

std::size_t segments(std::size_t size) {
  return std::max<std::size_t>(1, (size + 6) / 7);
}

TEST_P(PlainTransfer, UploadIsByteExact) {
  const std::size_t size = GetParam();
  Wire wire;
  wire.set_value(pattern(size));
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  wire.run(t);
  ASSERT_TRUE(t.finished());
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(t.result().data, pattern(size));
  EXPECT_EQ(t.bytes_done(), size);
  EXPECT_EQ(t.bytes_total(), size);
  const bool expedited = size >= 1 && size <= 4;
  // The initiate request, then one request per segment.
  EXPECT_EQ(wire.client_frames, expedited ? 1 : 1 + segments(size));
  EXPECT_FALSE(wire.server.busy());
  EXPECT_EQ(wire.server.counters().transfers_ok, 1u);
}

TEST_P(PlainTransfer, DownloadIsByteExact) {
  const std::size_t size = GetParam();
  Wire wire;
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(size), plain());
  EXPECT_EQ(t.bytes_total(), size);
  wire.run(t);
  ASSERT_TRUE(t.finished());
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_TRUE(t.result().data.empty());
  EXPECT_EQ(wire.written(), pattern(size));
  EXPECT_EQ(t.bytes_done(), size);
  const bool expedited = size >= 1 && size <= 4;
  EXPECT_EQ(wire.client_frames, expedited ? 1 : 1 + segments(size));
  EXPECT_EQ(wire.server_frames, wire.client_frames);  // one answer each
  EXPECT_EQ(wire.server.counters().transfers_ok, 1u);
}

INSTANTIATE_TEST_SUITE_P(SizeClasses, PlainTransfer,
                         ::testing::Values(0, 1, 4, 5, 7, 8, 889, 64 * 1024, 256 * 1024));

TEST(SdoTransfer, ExpeditedFramesAreCiA301s) {
  std::vector<Frame> out;
  auto down = SdoTransfer::download(kNode, {0x1017, 0}, {0xE8, 0x03}, plain());
  down.start(t0, out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0], Frame::standard(0x605, {0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0, 0}));
  auto up = SdoTransfer::upload(kNode, {0x1018, 1}, plain());
  up.start(t0, out);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[1], Frame::standard(0x605, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  // An expedited answer without size indication gives all four bytes.
  up.on_frame(Frame::standard(0x585, {0x42, 0x18, 0x10, 0x01, 1, 2, 3, 4}), t0, out);
  ASSERT_TRUE(up.finished());
  EXPECT_EQ(up.result().data, (std::vector<std::uint8_t>{1, 2, 3, 4}));
}

TEST(SdoTransfer, SegmentedDownloadFramesAreCiA301s) {
  std::vector<Frame> out;
  auto t = SdoTransfer::download(kNode, {0x2001, 0}, pattern(9), plain());
  t.start(t0, out);
  EXPECT_EQ(out.back(), Frame::standard(0x605, {0x21, 0x01, 0x20, 0x00, 9, 0, 0, 0}));
  t.on_frame(Frame::standard(0x585, {0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0}), t0, out);
  const auto p = pattern(9);
  EXPECT_EQ(out.back(), Frame::standard(0x605, {0x00, p[0], p[1], p[2], p[3], p[4], p[5], p[6]}));
  EXPECT_EQ(t.bytes_done(), 0u);
  t.on_frame(Frame::standard(0x585, {0x20, 0, 0, 0, 0, 0, 0, 0}), t0, out);
  EXPECT_EQ(t.bytes_done(), 7u);  // acknowledged, not merely sent
  // Toggled, 5 of 7 bytes unused, last.
  EXPECT_EQ(out.back(), Frame::standard(0x605, {0x1B, p[7], p[8], 0, 0, 0, 0, 0}));
  t.on_frame(Frame::standard(0x585, {0x30, 0, 0, 0, 0, 0, 0, 0}), t0, out);
  ASSERT_TRUE(t.finished());
  EXPECT_TRUE(t.result().ok());
  EXPECT_EQ(t.bytes_done(), 9u);
  EXPECT_EQ(out.size(), 3u);
}

TEST(SdoTransfer, ProgressGrowsWithEveryAnsweredSegment) {
  Wire wire;
  wire.set_value(pattern(889));
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  std::vector<std::size_t> seen;
  wire.server_filter = [&](Frame&) {
    seen.push_back(t.bytes_done());
    return true;
  };
  wire.run(t);
  ASSERT_TRUE(t.result().ok());
  EXPECT_EQ(t.bytes_total(), 889u);
  ASSERT_GE(seen.size(), 3u);
  EXPECT_EQ(seen[2], 7u);  // before the second segment: the first one's bytes
  EXPECT_TRUE(std::is_sorted(seen.begin(), seen.end()));
}

TEST(SdoTransfer, ServerRefusalIsTheResult) {
  Wire wire;
  auto t = SdoTransfer::download(kNode, kReadOnlyObject, pattern(100), plain());
  wire.run(t);
  ASSERT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, SdoAbort::write_read_only);
  EXPECT_EQ(wire.client_frames, 1u);  // an abort is never answered
}

// --- block transfers against the simulated server ----------------------------------------------

SdoTransferOptions block(std::uint8_t block_size = 127, std::uint8_t threshold = 0) {
  SdoTransferOptions options;
  options.block_size = block_size;
  options.protocol_switch_threshold = threshold;
  return options;
}

std::size_t sub_blocks(std::size_t size, std::size_t block_size) {
  return (segments(size) + block_size - 1) / block_size;
}

bool is_segment_of_sub_block(const Frame& f) {
  return f.id == 0x605 && f.data[0] != 0x80 && (f.data[0] & 0x7F) != 0;
}

class BlockTransfer : public ::testing::TestWithParam<std::size_t> {};

TEST_P(BlockTransfer, UploadIsByteExact) {
  const std::size_t size = GetParam();
  Wire wire;
  wire.set_value(pattern(size));
  auto t = SdoTransfer::upload(kNode, kUploadObject, block());
  wire.run(t);
  ASSERT_TRUE(t.finished());
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(t.result().data, pattern(size));
  EXPECT_EQ(t.bytes_done(), size);
  EXPECT_EQ(t.bytes_total(), size);
  // Initiate, start, one ack per sub-block, end.
  EXPECT_EQ(wire.client_frames, 3 + sub_blocks(size, 127));
  EXPECT_EQ(wire.server_frames, 2 + segments(size));
  EXPECT_FALSE(wire.server.busy());
  EXPECT_EQ(wire.server.counters().transfers_ok, 1u);
}

TEST_P(BlockTransfer, DownloadIsByteExact) {
  const std::size_t size = GetParam();
  Wire wire;
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(size), block());
  wire.run(t);
  ASSERT_TRUE(t.finished());
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(wire.written(), pattern(size));
  EXPECT_EQ(t.bytes_done(), size);
  if (size == 0) {
    // Nothing to put in a sub-block: a segmented download of size 0, one empty segment.
    EXPECT_EQ(wire.client_frames, 2u);
    EXPECT_EQ(wire.client_log[0].data[0], 0x21);
  } else {
    EXPECT_EQ(wire.client_frames, 2 + segments(size));  // initiate, segments, end
    EXPECT_EQ(wire.server_frames, 2 + sub_blocks(size, 127));
  }
  EXPECT_EQ(wire.server.counters().transfers_ok, 1u);
}

INSTANTIATE_TEST_SUITE_P(SizeClasses, BlockTransfer,
                         ::testing::Values(0, 1, 4, 5, 7, 8, 889, 64 * 1024, 256 * 1024));

class SmallBlocks : public ::testing::TestWithParam<std::uint8_t> {};

// 889 bytes are 127 segments: one full sub-block at 127, 19 at 7 (the last one short), 127 at 1.
TEST_P(SmallBlocks, UploadAcceptsAtMostTheClientsBlockSize) {
  const std::uint8_t block_size = GetParam();
  Wire wire;
  wire.set_value(pattern(889));
  auto t = SdoTransfer::upload(kNode, kUploadObject, block(block_size));
  EXPECT_EQ(t.bytes_total(), 0u);  // not known before the server says
  wire.run(t);
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(t.result().data, pattern(889));
  EXPECT_EQ(wire.client_log[0].data[4], block_size);
  std::size_t acks = 0;
  for (const Frame& f : wire.client_log) {
    if (f.data[0] != 0xA2) continue;
    ++acks;
    EXPECT_EQ(f.data[2], block_size);  // the next sub-block's size
    EXPECT_LE(f.data[1], block_size);
  }
  EXPECT_EQ(acks, sub_blocks(889, block_size));
}

TEST_P(SmallBlocks, DownloadSendsTheServersBlockSize) {
  const std::uint8_t block_size = GetParam();
  sim::SdoServerOptions options;
  options.max_block_size = block_size;
  Wire wire(options);
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(889), block());
  wire.run(t);
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(wire.written(), pattern(889));
  std::size_t segments_sent = 0;
  for (const Frame& f : wire.client_log) {
    if (f.data[0] == 0xC6 || (f.data[0] & 0xE3) == 0xC1) continue;  // initiate, end
    ++segments_sent;
    EXPECT_LE(f.data[0] & 0x7F, block_size);
  }
  EXPECT_EQ(segments_sent, 127u);
  EXPECT_EQ(wire.server_frames, 2 + sub_blocks(889, block_size));
}

INSTANTIATE_TEST_SUITE_P(BlockSizes, SmallBlocks, ::testing::Values(1, 7, 127));

TEST(SdoTransferBlock, InitiateFramesAreCiA301s) {
  std::vector<Frame> out;
  auto up = SdoTransfer::upload(kNode, {0x1F50, 1}, block(64, 16));
  up.start(t0, out);
  // ccs 5, client CRC, blksize 64, pst 16.
  EXPECT_EQ(out.back(), Frame::standard(0x605, {0xA4, 0x50, 0x1F, 0x01, 64, 16, 0, 0}));
  auto down = SdoTransfer::download(kNode, {0x1F50, 1}, pattern(300), block(64));
  down.start(t0, out);
  // ccs 6, client CRC, size indicated, 300 bytes.
  EXPECT_EQ(out.back(), Frame::standard(0x605, {0xC6, 0x50, 0x1F, 0x01, 0x2C, 0x01, 0, 0}));
}

TEST(SdoTransferBlock, ServerWithoutBlockTransferRefusesWithInvalidCommand) {
  sim::SdoServerOptions options;
  options.level = sim::SdoLevel::segmented;
  for (const bool upload : {true, false}) {
    Wire wire(options);
    wire.set_value(pattern(100));
    auto t = upload ? SdoTransfer::upload(kNode, kUploadObject, block())
                    : SdoTransfer::download(kNode, kDownloadObject, pattern(100), block());
    wire.run(t);
    ASSERT_TRUE(t.finished());
    // The server's abort is the result; the client does not fall back to segmented by itself.
    EXPECT_EQ(t.result().error, SdoAbort::invalid_command);
    EXPECT_EQ(wire.client_frames, 1u);
    EXPECT_EQ(wire.server_log.back().data[0], 0x80);
  }
}

TEST(SdoTransferBlock, ProtocolSwitchThresholdLetsTheServerAnswerPlainly) {
  struct Case {
    std::size_t size;
    std::uint8_t threshold;
    std::uint8_t server_specifier;  // of the initiate answer: 2 plain upload, 6 block upload
    std::size_t client_frames;
  };
  // Expedited: the initiate only; segmented: initiate and one request per segment; block:
  // initiate, start, ack, end.
  for (const Case c : {Case{4, 16, 2, 1}, Case{10, 16, 2, 3}, Case{16, 16, 2, 4},
                       Case{17, 16, 6, 4}, Case{4, 0, 6, 4}}) {
    Wire wire;
    wire.set_value(pattern(c.size));
    auto t = SdoTransfer::upload(kNode, kUploadObject, block(127, c.threshold));
    wire.run(t);
    ASSERT_TRUE(t.result().ok()) << c.size << ": " << t.result().error.message();
    EXPECT_EQ(t.result().data, pattern(c.size)) << c.size;
    EXPECT_EQ(t.bytes_total(), c.size);
    EXPECT_EQ(wire.server_log[0].data[0] >> 5, c.server_specifier) << c.size;
    EXPECT_EQ(wire.client_frames, c.client_frames) << c.size << " with pst " << int{c.threshold};
  }
  // Without a threshold a plain answer to a block initiate is a protocol error.
  std::vector<Frame> out;
  auto t = SdoTransfer::upload(kNode, kUploadObject, block());
  t.start(t0, out);
  t.on_frame(Frame::standard(0x585, {0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}), t0, out);
  EXPECT_EQ(t.result().error, SdoAbort::invalid_command);
  EXPECT_EQ(abort_code_of(out.back()), 0x05040001u);
}

TEST(SdoTransferBlock, LostSegmentInADownloadIsRepeatedFromTheAcknowledgedOne) {
  Wire wire;
  int segment = 0;
  wire.client_filter = [&](Frame& f) {
    return !(is_segment_of_sub_block(f) && f.data[0] != 0xC6 && ++segment == 3);
  };
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(889), block());
  wire.run(t);
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(wire.written(), pattern(889));
  // The server acknowledged seqno 2 of 127; the client repeated segments 3..127 as 1..125.
  ASSERT_GE(wire.server_log.size(), 2u);
  EXPECT_EQ(wire.server_log[1].data[0], 0xA2);
  EXPECT_EQ(wire.server_log[1].data[1], 2);
  EXPECT_EQ(wire.client_frames, 1 + 127 + 125 + 1);
  EXPECT_EQ(t.bytes_done(), 889u);
}

TEST(SdoTransferBlock, LostLastSegmentOfASubBlockEndsInTheTimeout) {
  Wire wire;
  SdoTransferOptions options = block();
  options.timeout = 500ms;
  wire.client_filter = [&](Frame& f) { return f.data[0] != (0x80 | 127); };
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(889), options);
  wire.run(t);
  // Nobody knows the sub-block ended: the client's timeout runs out first and tells the server.
  EXPECT_EQ(t.result().error, SdoAbort::timeout);
  EXPECT_EQ(wire.now, t0 + 500ms);
  EXPECT_EQ(abort_code_of(wire.client_log.back()), 0x05040000u);
  EXPECT_FALSE(wire.server.busy());
  EXPECT_EQ(t.bytes_done(), 0u);
}

TEST(SdoTransferBlock, LostSegmentInAnUploadIsAcknowledgedForRepetition) {
  Wire wire;
  wire.set_value(pattern(889));
  int frame = 0;
  wire.server_filter = [&](Frame&) { return ++frame != 4; };  // initiate answer, then segment 3
  auto t = SdoTransfer::upload(kNode, kUploadObject, block());
  wire.run(t);
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(t.result().data, pattern(889));
  const Frame& first_ack = wire.client_log[2];
  EXPECT_EQ(first_ack.data[0], 0xA2);
  EXPECT_EQ(first_ack.data[1], 2);
  EXPECT_EQ(wire.server_frames, 1 + 127 + 125 + 1);
}

TEST(SdoTransferBlock, CorruptCrcInADownloadIsRefusedByTheServer) {
  Wire wire;
  wire.client_filter = [&](Frame& f) {
    if ((f.data[0] & 0xE3) == 0xC1) f.data[1] ^= 0x01;  // end block download
    return true;
  };
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(20), block());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::crc_error);
  EXPECT_EQ(abort_code_of(wire.server_log.back()), 0x05040004u);
  EXPECT_EQ((wire.client_log.back().data[0] & 0xE3), 0xC1);  // no answer to the server's abort
  EXPECT_TRUE(wire.written().empty());
}

TEST(SdoTransferBlock, CorruptCrcInAnUploadAborts) {
  Wire wire;
  wire.set_value(pattern(20));
  wire.server_filter = [&](Frame& f) {
    if ((f.data[0] & 0xE1) == 0xC1) f.data[2] ^= 0x80;  // end block upload
    return true;
  };
  auto t = SdoTransfer::upload(kNode, kUploadObject, block());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::crc_error);
  EXPECT_TRUE(t.result().data.empty());
  const Frame& abort = wire.client_log.back();
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(abort_code_of(abort), 0x05040004u);
  EXPECT_FALSE(wire.server.busy());
  EXPECT_EQ(wire.server.counters().transfers_ok, 0u);
}

TEST(SdoTransferBlock, ServerAbortInsideASubBlockIsTheResult) {
  Wire wire;
  wire.set_value(pattern(889));
  int frame = 0;
  wire.server_filter = [&](Frame& f) {
    if (++frame == 5) f = sdo::abort_response(kNode, kUploadObject, SdoAbort::hardware_error);
    return true;
  };
  auto t = SdoTransfer::upload(kNode, kUploadObject, block());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::hardware_error);
  EXPECT_EQ(wire.client_frames, 2u);  // initiate, start; the abort is not answered
  EXPECT_EQ(t.bytes_done(), 21u);
}

TEST(SdoTransferBlock, AbortDuringADownloadSubBlockFreesTheServer) {
  Wire wire;
  std::vector<Frame> out;
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(2000), block());
  t.start(t0, out);
  std::vector<Frame> answers;
  wire.server.on_request(out[0], t0, answers);
  t.on_frame(answers[0], t0, out);
  ASSERT_EQ(out.size(), 1u + 127u);
  for (std::size_t i = 1; i < 50; ++i) wire.server.on_request(out[i], t0, answers);
  EXPECT_TRUE(wire.server.busy());
  t.abort(make_error_code(SdoAbort::local_control), out);
  EXPECT_EQ(t.result().error, SdoAbort::local_control);
  EXPECT_EQ(out.back(), sdo::abort_request(kNode, kDownloadObject, SdoAbort::local_control));
  wire.server.on_request(out.back(), t0, answers);
  EXPECT_FALSE(wire.server.busy());
  EXPECT_EQ(wire.server.counters().aborts_received, 1u);
}

// --- block protocol details the simulated server does not exercise ------------------------------

TEST(SdoTransferBlock, DownloadFollowsTheServersChangingBlockSize) {
  std::vector<Frame> out;
  const auto data = pattern(50);  // 8 segments, the last one with 1 byte
  auto t = SdoTransfer::download(kNode, {0x2001, 0}, data, block());
  t.start(t0, out);
  out.clear();
  t.on_frame(Frame::standard(0x585, {0xA4, 0x01, 0x20, 0x00, 4, 0, 0, 0}), t0, out);
  ASSERT_EQ(out.size(), 4u);
  EXPECT_EQ(out[0], Frame::standard(0x605, {0x01, data[0], data[1], data[2], data[3], data[4],
                                            data[5], data[6]}));
  EXPECT_EQ(out[3].data[0], 0x04);
  out.clear();
  t.on_frame(Frame::standard(0x585, {0xA2, 4, 2, 0, 0, 0, 0, 0}), t0, out);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].data[0], 0x01);
  EXPECT_EQ(out[0].data[1], data[28]);
  EXPECT_EQ(t.bytes_done(), 28u);
  out.clear();
  t.on_frame(Frame::standard(0x585, {0xA2, 2, 3, 0, 0, 0, 0, 0}), t0, out);
  ASSERT_EQ(out.size(), 2u);  // two segments left, the second one last
  EXPECT_EQ(out[1], Frame::standard(0x605, {0x82, data[49], 0, 0, 0, 0, 0, 0}));
  out.clear();
  t.on_frame(Frame::standard(0x585, {0xA2, 2, 3, 0, 0, 0, 0, 0}), t0, out);
  ASSERT_EQ(out.size(), 1u);
  const std::uint16_t crc = crc16_xmodem(data);
  // End: 6 bytes of the last segment unused, the CRC little-endian.
  EXPECT_EQ(out[0], Frame::standard(0x605, {0xD9, static_cast<std::uint8_t>(crc),
                                            static_cast<std::uint8_t>(crc >> 8), 0, 0, 0, 0, 0}));
  EXPECT_FALSE(t.finished());
  t.on_frame(Frame::standard(0x585, {0xA1, 0, 0, 0, 0, 0, 0, 0}), t0, out);
  ASSERT_TRUE(t.finished());
  EXPECT_TRUE(t.result().ok());
  EXPECT_EQ(t.bytes_done(), 50u);
}

TEST(SdoTransferBlock, BadAcknowledgementsAbort) {
  struct Case {
    Frame ack;
    SdoAbort expected;
  };
  for (const Case& c :
       {Case{Frame::standard(0x585, {0xA2, 5, 4, 0, 0, 0, 0, 0}),
             SdoAbort::invalid_sequence},  // acks more than was sent
        Case{Frame::standard(0x585, {0xA2, 4, 0, 0, 0, 0, 0, 0}), SdoAbort::invalid_block_size},
        Case{Frame::standard(0x585, {0xA2, 4, 128, 0, 0, 0, 0, 0}), SdoAbort::invalid_block_size},
        Case{Frame::standard(0x585, {0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0}),
             SdoAbort::invalid_command}}) {
    std::vector<Frame> out;
    auto t = SdoTransfer::download(kNode, {0x2001, 0}, pattern(50), block());
    t.start(t0, out);
    t.on_frame(Frame::standard(0x585, {0xA4, 0x01, 0x20, 0x00, 4, 0, 0, 0}), t0, out);
    t.on_frame(c.ack, t0, out);
    ASSERT_TRUE(t.finished());
    EXPECT_EQ(t.result().error, c.expected);
    EXPECT_EQ(abort_code_of(out.back()), static_cast<std::uint32_t>(c.expected));
  }
}

TEST(SdoTransferBlock, UploadSegmentBeyondTheBlockSizeAborts) {
  std::vector<Frame> out;
  auto t = SdoTransfer::upload(kNode, {0x2000, 0}, block(4));
  t.start(t0, out);
  t.on_frame(Frame::standard(0x585, {0xC6, 0x00, 0x20, 0x00, 100, 0, 0, 0}), t0, out);
  EXPECT_EQ(out.back().data[0], 0xA3);  // start
  EXPECT_EQ(t.bytes_total(), 100u);
  t.on_frame(Frame::standard(0x585, {0x05, 1, 2, 3, 4, 5, 6, 7}), t0, out);
  EXPECT_EQ(t.result().error, SdoAbort::invalid_sequence);
  EXPECT_EQ(abort_code_of(out.back()), 0x05040003u);
}

TEST(SdoTransferBlock, UploadSubBlockTimeoutRestartsWithEverySegment) {
  SdoTransferOptions options = block(4);
  options.timeout = 100ms;
  std::vector<Frame> out;
  auto t = SdoTransfer::upload(kNode, {0x2000, 0}, options);
  t.start(t0, out);
  t.on_frame(Frame::standard(0x585, {0xC6, 0x00, 0x20, 0x00, 100, 0, 0, 0}), t0 + 10ms, out);
  t.on_frame(Frame::standard(0x585, {0x01, 1, 2, 3, 4, 5, 6, 7}), t0 + 90ms, out);
  EXPECT_EQ(t.deadline(), t0 + 190ms);
  t.on_timeout(t0 + 189ms, out);
  EXPECT_FALSE(t.finished());
  t.on_timeout(t0 + 190ms, out);
  EXPECT_EQ(t.result().error, SdoAbort::timeout);
  EXPECT_EQ(abort_code_of(out.back()), 0x05040000u);
}

// --- protocol errors ---------------------------------------------------------------------------

TEST(SdoTransfer, ToggleErrorInAnUploadSegmentAborts) {
  Wire wire;
  wire.set_value(pattern(50));
  int segment = 0;
  wire.server_filter = [&](Frame& f) {
    if ((f.data[0] >> 5) == sdo::scs::upload_segment && ++segment == 3) f.data[0] ^= sdo::kToggle;
    return true;
  };
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::toggle_bit);
  EXPECT_TRUE(t.result().data.empty());
  EXPECT_EQ(t.bytes_done(), 14u);
  ASSERT_FALSE(wire.client_log.empty());
  const Frame& abort = wire.client_log.back();
  EXPECT_EQ(abort.id, 0x605u);
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(sdo::read_multiplexer(abort), kUploadObject);
  EXPECT_EQ(abort_code_of(abort), 0x05030000u);
  EXPECT_FALSE(wire.server.busy());  // the abort freed the server
}

TEST(SdoTransfer, ToggleErrorInADownloadAcknowledgementAborts) {
  Wire wire;
  int ack = 0;
  wire.server_filter = [&](Frame& f) {
    if ((f.data[0] >> 5) == sdo::scs::download_segment && ++ack == 2) f.data[0] ^= sdo::kToggle;
    return true;
  };
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(50), plain());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::toggle_bit);
  EXPECT_EQ(t.bytes_done(), 7u);
  EXPECT_EQ(abort_code_of(wire.client_log.back()), 0x05030000u);
  EXPECT_FALSE(wire.server.busy());
}

TEST(SdoTransfer, UnexpectedAnswerAbortsWithInvalidCommand) {
  std::vector<Frame> out;
  auto t = SdoTransfer::upload(kNode, {0x2000, 0}, plain());
  t.start(t0, out);
  // A download response naming our object does not answer an upload.
  t.on_frame(Frame::standard(0x585, {0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}), t0, out);
  ASSERT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, SdoAbort::invalid_command);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(abort_code_of(out[1]), 0x05040001u);
}

TEST(SdoTransfer, UploadLongerOrShorterThanIndicatedAborts) {
  for (const bool longer : {true, false}) {
    std::vector<Frame> out;
    auto t = SdoTransfer::upload(kNode, {0x2000, 0}, plain());
    t.start(t0, out);
    t.on_frame(Frame::standard(0x585, {0x41, 0x00, 0x20, 0x00, 10, 0, 0, 0}), t0, out);
    t.on_frame(Frame::standard(0x585, {0x00, 1, 2, 3, 4, 5, 6, 7}), t0, out);
    // Second segment: 7 bytes (14 > 10) or 1 byte and last (8 < 10).
    t.on_frame(longer ? Frame::standard(0x585, {0x10, 1, 2, 3, 4, 5, 6, 7})
                      : Frame::standard(0x585, {0x1D, 1, 0, 0, 0, 0, 0, 0}),
               t0, out);
    ASSERT_TRUE(t.finished());
    EXPECT_EQ(t.result().error, longer ? SdoAbort::length_too_high : SdoAbort::length_too_low);
    EXPECT_EQ(abort_code_of(out.back()), longer ? 0x06070012u : 0x06070013u);
  }
}

// --- timeouts, aborts, late answers ------------------------------------------------------------

TEST(SdoTransfer, TimeoutOnlyAtTheDeadlineAndTellsTheServer) {
  SdoTransferOptions options;
  options.timeout = 300ms;
  std::vector<Frame> out;
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(20), options);
  EXPECT_EQ(t.deadline(), TimePoint::max());  // not started: nothing awaited
  t.start(t0, out);
  EXPECT_EQ(t.deadline(), t0 + 300ms);
  // The answer comes late but in time; the next answer is due a full timeout after it.
  t.on_frame(Frame::standard(0x585, {0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0}), t0 + 250ms, out);
  EXPECT_EQ(t.deadline(), t0 + 550ms);
  t.on_timeout(t0 + 549ms, out);
  EXPECT_FALSE(t.finished());
  EXPECT_EQ(out.size(), 2u);
  t.on_timeout(t0 + 550ms, out);
  ASSERT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, SdoAbort::timeout);
  EXPECT_EQ(t.deadline(), TimePoint::max());
  ASSERT_EQ(out.size(), 3u);
  EXPECT_EQ(out[2].id, 0x605u);
  EXPECT_EQ(out[2].data[0], 0x80);
  EXPECT_EQ(abort_code_of(out[2]), 0x05040000u);
  t.on_timeout(t0 + 10s, out);  // once finished, nothing more
  EXPECT_EQ(out.size(), 3u);
}

TEST(SdoTransfer, LostAnswerEndsInTimeoutAgainstTheSimulatedServer) {
  Wire wire;
  wire.set_value(pattern(100));
  int answer = 0;
  wire.server_filter = [&](Frame&) { return ++answer != 4; };
  SdoTransferOptions options;
  options.timeout = 200ms;
  auto t = SdoTransfer::upload(kNode, kUploadObject, options);
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::timeout);
  EXPECT_EQ(wire.now, t0 + 200ms);  // all answers came at t0: the lost one was due at t0 + 200 ms
  EXPECT_EQ(abort_code_of(wire.client_log.back()), 0x05040000u);
  EXPECT_FALSE(wire.server.busy());
}

TEST(SdoTransfer, ServerAbortMidTransferIsTheResult) {
  Wire wire;
  wire.set_value(pattern(100));
  int answer = 0;
  wire.server_filter = [&](Frame& f) {
    if (++answer == 3) f = sdo::abort_response(kNode, kUploadObject, SdoAbort::hardware_error);
    return true;
  };
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  wire.run(t);
  EXPECT_EQ(t.result().error, SdoAbort::hardware_error);
  EXPECT_EQ(t.bytes_done(), 7u);
  EXPECT_EQ(wire.client_frames, 3u);  // initiate, two segment requests; no answer to the abort
}

TEST(SdoTransfer, AbortNamingNoObjectEndsAnOpenSegmentedTransfer) {
  std::vector<Frame> out;
  auto t = SdoTransfer::download(kNode, {0x2001, 0}, pattern(20), plain());
  t.start(t0, out);
  // During the initiate an abort must name our object: one naming none is ignored.
  t.on_frame(sdo::abort_response(kNode, {}, SdoAbort::invalid_command), t0, out);
  EXPECT_FALSE(t.finished());
  t.on_frame(Frame::standard(0x585, {0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0}), t0, out);
  // A server that lost the transfer (it timed out or was reset) answers our segment so.
  t.on_frame(sdo::abort_response(kNode, {}, SdoAbort::invalid_command), t0, out);
  ASSERT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, SdoAbort::invalid_command);
  EXPECT_EQ(out.size(), 2u);
}

TEST(SdoTransfer, LateAnswersOfAnEarlierTransferAreIgnored) {
  Wire wire;
  wire.set_value(pattern(30));
  // An earlier transfer of 1018h:01 timed out; its answers arrive now, during ours: before our
  // initiate is answered and between our segments.
  const Frame late[] = {Frame::standard(0x585, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4}),
                        sdo::download_response(kNode, {0x1017, 0}),
                        sdo::abort_response(kNode, {0x1018, 1}, SdoAbort::timeout)};
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  std::vector<Frame> sent_for_late;
  int answer = 0;
  wire.server_filter = [&](Frame&) {
    if (++answer == 1 || answer == 3) {
      for (const Frame& f : late) t.on_frame(f, wire.now, sent_for_late);
    }
    return true;
  };
  wire.run(t);
  ASSERT_TRUE(t.result().ok()) << t.result().error.message();
  EXPECT_EQ(t.result().data, pattern(30));
  EXPECT_TRUE(sent_for_late.empty());
  std::vector<Frame> out;
  // Other nodes' frames and non-SDO frames are no answers either.
  auto other = SdoTransfer::upload(kNode, kUploadObject, plain());
  other.start(t0, out);
  other.on_frame(Frame::standard(0x586, {0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}), t0, out);
  other.on_frame(Frame::standard(0x585, {0x43, 0x00, 0x20}), t0, out);
  other.on_frame(Frame::standard(0x705, {0x7F}), t0, out);
  EXPECT_FALSE(other.finished());
}

TEST(SdoTransfer, AbortWhileOpenTellsTheServerAndFinishesWithTheReason) {
  Wire wire;
  auto t = SdoTransfer::download(kNode, kDownloadObject, pattern(100), plain());
  std::vector<Frame> out;
  t.start(t0, out);
  std::vector<Frame> answers;
  wire.server.on_request(out[0], t0, answers);
  t.on_frame(answers[0], t0, out);
  ASSERT_EQ(out.size(), 2u);
  wire.server.on_request(out[1], t0, answers);
  EXPECT_TRUE(wire.server.busy());
  t.abort(make_error_code(SdoAbort::local_control), out);
  ASSERT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, SdoAbort::local_control);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_EQ(out[2], sdo::abort_request(kNode, kDownloadObject, SdoAbort::local_control));
  wire.server.on_request(out[2], t0, answers);
  EXPECT_FALSE(wire.server.busy());
  // The server's answer to the segment, arriving after the abort, changes nothing.
  t.on_frame(answers.back(), t0, out);
  t.abort(make_error_code(SdoAbort::timeout), out);
  EXPECT_EQ(t.result().error, SdoAbort::local_control);
  EXPECT_EQ(out.size(), 3u);
}

TEST(SdoTransfer, AbortBeforeStartSendsNothing) {
  auto t = SdoTransfer::upload(kNode, kUploadObject, plain());
  std::vector<Frame> out;
  t.abort(std::make_error_code(std::errc::operation_canceled), out);
  EXPECT_TRUE(t.finished());
  EXPECT_EQ(t.result().error, std::errc::operation_canceled);
  EXPECT_TRUE(out.empty());
}

TEST(SdoTransfer, RejectsInvalidArguments) {
  EXPECT_THROW(SdoTransfer::upload(0, kUploadObject, plain()), std::invalid_argument);
  EXPECT_THROW(SdoTransfer::upload(128, kUploadObject, plain()), std::invalid_argument);
  SdoTransferOptions too_big;
  too_big.block_size = 128;
  EXPECT_THROW(SdoTransfer::download(kNode, kDownloadObject, {1}, too_big), std::invalid_argument);
  EXPECT_NO_THROW(SdoTransfer::download(kMaxNodeId, kDownloadObject, {}, plain()));
}

}  // namespace
}  // namespace canbridge::canopen
