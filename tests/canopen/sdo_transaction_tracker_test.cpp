// The per-channel SDO tracker: values of every listed object rewritten in every transfer mode
// (expedited, segmented, block with and without CRC), both directions; unlisted transfers, aborts,
// restarts and odd frames pass bit-exact. Frames follow the layouts of sim/sdo_server.cpp.
#include "canopen/sdo_transaction_tracker.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <map>
#include <random>
#include <span>
#include <vector>

#include "canopen/crc16.hpp"

namespace canbridge::canopen::sdo {
namespace {

constexpr NodeId kLocalNode = 5;     // the node on its module bus
constexpr NodeId kSurfaceNode = 37;  // as the master addresses it

// A node-id map as the bridge builds it: `table` maps local node ids to surface ones, COB-IDs of
// the predefined connection set follow their node.
IdMapping node_map(std::map<NodeId, NodeId> table) {
  auto node = [table](NodeId n) -> std::optional<NodeId> {
    const auto it = table.find(n);
    if (it == table.end()) return std::nullopt;
    return it->second;
  };
  auto cob = [node](std::uint32_t cob_id) -> std::optional<std::uint32_t> {
    const auto a = split_predefined(cob_id);
    if (!a) return std::nullopt;
    const auto mapped = node(a->node);
    if (!mapped) return std::nullopt;
    return a->function_base + std::uint32_t{*mapped};
  };
  return {cob, node};
}

std::map<NodeId, NodeId> module1_table() {  // the default map of module 1: local n -> n + 32
  std::map<NodeId, NodeId> t;
  for (NodeId n = 1; n <= 31; ++n) t[n] = static_cast<NodeId>(n + 32);
  return t;
}
std::map<NodeId, NodeId> inverse(const std::map<NodeId, NodeId>& table) {
  std::map<NodeId, NodeId> out;
  for (const auto& [a, b] : table) out[b] = a;
  return out;
}

std::array<std::uint8_t, 4> le(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

// --- frames, as sim/sdo_server.cpp lays them out ----------------------------------------------

can::Frame frame(std::uint32_t cob, std::uint8_t byte0, Multiplexer mux = {},
                 std::uint32_t value = 0) {
  can::Frame f;
  f.id = cob;
  f.len = 8;
  f.data[0] = byte0;
  write_multiplexer(f, mux);
  write_u32(f, 4, value);
  return f;
}
can::Frame request(std::uint8_t byte0, Multiplexer mux = {}, std::uint32_t value = 0) {
  return frame(request_cob(kSurfaceNode), byte0, mux, value);
}
can::Frame response(std::uint8_t byte0, Multiplexer mux = {}, std::uint32_t value = 0) {
  return frame(response_cob(kLocalNode), byte0, mux, value);
}
// byte0, then up to 7 data bytes (the rest zero).
can::Frame with_data(can::Frame f, std::span<const std::uint8_t> data) {
  std::fill(f.data.begin() + 1, f.data.end(), 0);
  std::copy_n(data.begin(), std::min(data.size(), kSegmentBytes), f.data.begin() + 1);
  return f;
}

std::uint8_t unused(std::size_t length) {
  return static_cast<std::uint8_t>(kSegmentBytes - length);
}

// Segmented.
can::Frame initiate_segmented_download(Multiplexer mux, std::uint32_t size) {
  return request(0x21, mux, size);  // ccs 1, e = 0, s = 1
}
can::Frame download_segment(bool toggle, std::span<const std::uint8_t> data, bool last) {
  return with_data(request(static_cast<std::uint8_t>((toggle ? 0x10 : 0) |
                                                     unused(data.size()) << 1 | (last ? 1 : 0))),
                   data);
}
can::Frame download_segment_response(bool toggle) {
  return response(toggle ? 0x30 : 0x20);
}
can::Frame upload_segment_request(bool toggle) {
  return request(toggle ? 0x70 : 0x60);
}
can::Frame upload_segment(bool toggle, std::span<const std::uint8_t> data, bool last) {
  return with_data(response(static_cast<std::uint8_t>((toggle ? 0x10 : 0) |
                                                      unused(data.size()) << 1 | (last ? 1 : 0))),
                   data);
}

// Block download.
can::Frame initiate_block_download(Multiplexer mux, bool crc, std::optional<std::uint32_t> size) {
  return request(static_cast<std::uint8_t>(0xC0 | (crc ? 0x04 : 0) | (size ? 0x02 : 0)), mux,
                 size.value_or(0));
}
can::Frame block_download_initiated(Multiplexer mux, bool crc, std::uint8_t blksize = 127) {
  can::Frame f = response(static_cast<std::uint8_t>(0xA0 | (crc ? 0x04 : 0)), mux);
  f.data[4] = blksize;
  f.data[5] = f.data[6] = f.data[7] = 0;
  return f;
}
can::Frame block_ack(bool from_client, std::uint8_t ackseq, std::uint8_t blksize = 127) {
  can::Frame f = from_client ? request(0xA2) : response(0xA2);
  f.data[1] = ackseq;
  f.data[2] = blksize;
  return f;
}
can::Frame block_segment(bool from_client, std::uint8_t seqno, std::span<const std::uint8_t> data,
                         bool last) {
  const auto byte0 = static_cast<std::uint8_t>((last ? 0x80 : 0) | seqno);
  return with_data(from_client ? request(byte0) : response(byte0), data);
}
// End block download request / end block upload response: n, CRC.
can::Frame block_end(bool from_client, std::size_t last_length, std::uint16_t crc) {
  const auto byte0 = static_cast<std::uint8_t>(0xC1 | unused(last_length) << 2);
  can::Frame f = from_client ? request(byte0) : response(byte0);
  f.data[1] = static_cast<std::uint8_t>(crc);
  f.data[2] = static_cast<std::uint8_t>(crc >> 8);
  return f;
}
std::uint16_t crc_of(const can::Frame& end) {
  return static_cast<std::uint16_t>(end.data[1] | end.data[2] << 8);
}

// Block upload.
can::Frame initiate_block_upload(Multiplexer mux, bool crc, std::uint8_t blksize = 127,
                                 std::uint8_t pst = 0) {
  can::Frame f = request(static_cast<std::uint8_t>(0xA0 | (crc ? 0x04 : 0)), mux);
  f.data[4] = blksize;
  f.data[5] = pst;
  return f;
}
can::Frame block_upload_initiated(Multiplexer mux, bool crc, std::uint32_t size) {
  return response(static_cast<std::uint8_t>(0xC2 | (crc ? 0x04 : 0)), mux, size);
}
can::Frame start_block_upload() {
  return request(0xA3);
}

// --- the channel -------------------------------------------------------------------------------

// One tracker between a master (surface ids) and node 5 (module 1 ids: surface = local + 32).
struct Channel {
  ValueTransferTracker tracker;
  IdMapping to_local = node_map(inverse(module1_table()));
  IdMapping to_surface = node_map(module1_table());

  // Master -> node: returns what happened; `f` becomes what the node receives.
  ValueRewrite send(can::Frame& f) { return tracker.on_request(f, to_local); }
  ValueRewrite reply(can::Frame& f) { return tracker.on_response(f, to_surface); }
  // Frames that must cross untouched.
  void pass(can::Frame f) {
    const can::Frame before = f;
    EXPECT_EQ(send(f), ValueRewrite::unchanged) << can::to_string(before);
    EXPECT_EQ(f, before) << can::to_string(before);
  }
  void pass_reply(can::Frame f) {
    const can::Frame before = f;
    EXPECT_EQ(reply(f), ValueRewrite::unchanged) << can::to_string(before);
    EXPECT_EQ(f, before) << can::to_string(before);
  }
};

// Every object family of value_kind's comment, with a value as the node holds it and as the
// master sees it.
struct Family {
  const char* name;
  Multiplexer mux;
  std::uint32_t local;
  std::uint32_t surface;
  std::size_t size;  // bytes on the wire
  std::vector<std::uint8_t> local_bytes() const {
    const auto b = le(local);
    return {b.begin(), b.begin() + static_cast<std::ptrdiff_t>(size)};
  }
  std::vector<std::uint8_t> surface_bytes() const {
    const auto b = le(surface);
    return {b.begin(), b.begin() + static_cast<std::ptrdiff_t>(size)};
  }
};

const Family kFamilies[] = {
    {"1200h sub1 SDO server rx", {0x1200, 1}, 0x605, 0x625, 4},
    {"1200h sub2 SDO server tx", {0x1200, 2}, 0x585, 0x5A5, 4},
    {"1280h sub1 SDO client tx", {0x1280, 1}, 0x607, 0x627, 4},
    {"1280h sub2 SDO client rx", {0x12FF, 2}, 0x587, 0x5A7, 4},
    {"1280h sub3 server node", {0x1280, 3}, 7, 39, 1},
    {"1400h sub1 RPDO1", {0x1400, 1}, 0x205, 0x225, 4},
    {"15FFh sub1 RPDO, invalid", {0x15FF, 1}, 0x80000505u, 0x80000525u, 4},
    {"1800h sub1 TPDO1, no RTR", {0x1800, 1}, 0x40000185u, 0x400001A5u, 4},
    {"19FFh sub1 TPDO, both flags", {0x19FF, 1}, 0xC0000285u, 0xC00002A5u, 4},
    {"1014h EMCY", {0x1014, 0}, 0x85, 0xA5, 4},
    {"1016h sub1 consumer", {0x1016, 1}, 0x000700C8u, 0x002700C8u, 4},
    {"1016h sub127 consumer", {0x1016, 127}, 0x001F0064u, 0x003F0064u, 4},
    // Issue 14: the emergency consumer and the SDO server's client node id (and every sub 3).
    {"1028h sub1 EMCY consumer", {0x1028, 1}, 0x87, 0xA7, 4},
    {"1028h sub127 EMCY consumer, invalid", {0x1028, 127}, 0x8000009Fu, 0x800000BFu, 4},
    {"12FFh sub3 server node", {0x12FF, 3}, 1, 33, 1},
    {"1200h sub3 client node", {0x1200, 3}, 7, 39, 1},
    {"127Fh sub3 client node", {0x127F, 3}, 31, 63, 1},
};

void expect_data(const can::Frame& f, std::span<const std::uint8_t> expected) {
  EXPECT_TRUE(std::equal(expected.begin(), expected.end(), f.data.begin() + 1))
      << can::to_string(f);
}

// --- every listed object, every mode ----------------------------------------------------------

TEST(SdoValueTransferTracker, ExpeditedTransfersMatchTheStatelessRewrite) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Channel ch;
    const auto surface = c.surface_bytes();
    can::Frame down = download_request(kSurfaceNode, c.mux, surface);
    can::Frame stateless = down;
    EXPECT_EQ(rewrite_request(stateless, ch.to_local), ValueRewrite::rewritten);
    EXPECT_EQ(ch.send(down), ValueRewrite::rewritten);
    EXPECT_EQ(down, stateless);
    EXPECT_EQ(c.size == 1 ? down.data[4] : read_u32(down, 4), c.local);
    ch.pass_reply(download_response(kLocalNode, c.mux));
    EXPECT_TRUE(ch.tracker.idle());

    ch.pass(upload_request(kSurfaceNode, c.mux));
    const auto local = c.local_bytes();
    can::Frame up = upload_response(kLocalNode, c.mux, local);
    stateless = up;
    EXPECT_EQ(rewrite_response(stateless, ch.to_surface), ValueRewrite::rewritten);
    EXPECT_EQ(ch.reply(up), ValueRewrite::rewritten);
    EXPECT_EQ(up, stateless);
    EXPECT_EQ(c.size == 1 ? up.data[4] : read_u32(up, 4), c.surface);
    EXPECT_TRUE(ch.tracker.idle());
  }
}

TEST(SdoValueTransferTracker, SegmentedDownloadRewritesTheOneDataSegment) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Channel ch;
    ch.pass(initiate_segmented_download(c.mux, static_cast<std::uint32_t>(c.size)));
    ch.pass_reply(download_response(kLocalNode, c.mux));
    can::Frame segment = download_segment(false, c.surface_bytes(), true);
    const std::uint8_t command = segment.data[0];
    EXPECT_EQ(ch.send(segment), ValueRewrite::rewritten);
    EXPECT_EQ(segment.data[0], command);  // t, n, c untouched
    expect_data(segment, c.local_bytes());
    ch.pass_reply(download_segment_response(false));
    EXPECT_TRUE(ch.tracker.idle());
  }
}

TEST(SdoValueTransferTracker, SegmentedUploadRewritesTheOneDataSegment) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Channel ch;
    ch.pass(upload_request(kSurfaceNode, c.mux));
    ch.pass_reply(segmented_upload_response(kLocalNode, c.mux, static_cast<std::uint32_t>(c.size)));
    ch.pass(upload_segment_request(false));
    can::Frame segment = upload_segment(false, c.local_bytes(), true);
    const std::uint8_t command = segment.data[0];
    EXPECT_EQ(ch.reply(segment), ValueRewrite::rewritten);
    EXPECT_EQ(segment.data[0], command);
    expect_data(segment, c.surface_bytes());
    EXPECT_TRUE(ch.tracker.idle());
  }
}

// The master writes `c` by block download; returns the end frame as the node receives it.
can::Frame block_download(Channel& ch, const Family& c, bool client_crc, bool server_crc,
                          std::optional<std::uint32_t> size) {
  ch.pass(initiate_block_download(c.mux, client_crc, size));
  ch.pass_reply(block_download_initiated(c.mux, server_crc));
  const auto surface = c.surface_bytes();
  can::Frame segment = block_segment(true, 1, surface, true);
  EXPECT_EQ(ch.send(segment), ValueRewrite::rewritten);
  EXPECT_EQ(segment.data[0], 0x81);
  expect_data(segment, c.local_bytes());
  ch.pass_reply(block_ack(false, 1));
  can::Frame end = block_end(true, c.size, crc16_xmodem(surface));
  const ValueRewrite result = ch.send(end);
  EXPECT_EQ(result, client_crc && server_crc ? ValueRewrite::rewritten : ValueRewrite::unchanged);
  EXPECT_EQ(end.data[0], 0xC1 | unused(c.size) << 2);
  ch.pass_reply(response(0xA1));
  EXPECT_TRUE(ch.tracker.idle());
  return end;
}

TEST(SdoValueTransferTracker, BlockDownloadWithCrcCarriesTheCrcOfTheRewrittenValue) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Channel ch;
    const can::Frame end = block_download(ch, c, true, true, static_cast<std::uint32_t>(c.size));
    EXPECT_EQ(crc_of(end), crc16_xmodem(c.local_bytes()));
    EXPECT_NE(crc_of(end), crc16_xmodem(c.surface_bytes()));
    // Without an indicated size the segment is read as holding the value, the same way.
    Channel unsized;
    EXPECT_EQ(crc_of(block_download(unsized, c, true, true, std::nullopt)),
              crc16_xmodem(c.local_bytes()));
  }
}

TEST(SdoValueTransferTracker, BlockDownloadWithoutCrcLeavesTheCrcFieldAlone) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    const std::uint16_t sent = crc16_xmodem(c.surface_bytes());
    Channel no_client_crc;
    EXPECT_EQ(crc_of(block_download(no_client_crc, c, false, true, std::nullopt)), sent);
    Channel no_server_crc;  // CRC is in use only when both support it (CiA 301)
    EXPECT_EQ(crc_of(block_download(no_server_crc, c, true, false, std::nullopt)), sent);
  }
}

// The master reads `c` by block upload; returns the end frame as the master receives it.
can::Frame block_upload(Channel& ch, const Family& c, bool client_crc, bool server_crc) {
  ch.pass(initiate_block_upload(c.mux, client_crc));
  ch.pass_reply(block_upload_initiated(c.mux, server_crc, static_cast<std::uint32_t>(c.size)));
  ch.pass(start_block_upload());
  const auto local = c.local_bytes();
  can::Frame segment = block_segment(false, 1, local, true);
  EXPECT_EQ(ch.reply(segment), ValueRewrite::rewritten);
  EXPECT_EQ(segment.data[0], 0x81);
  expect_data(segment, c.surface_bytes());
  ch.pass(block_ack(true, 1));
  can::Frame end = block_end(false, c.size, crc16_xmodem(local));
  const ValueRewrite result = ch.reply(end);
  EXPECT_EQ(result, client_crc && server_crc ? ValueRewrite::rewritten : ValueRewrite::unchanged);
  EXPECT_EQ(end.data[0], 0xC1 | unused(c.size) << 2);
  ch.pass(request(0xA1));  // end block upload response
  EXPECT_TRUE(ch.tracker.idle());
  return end;
}

TEST(SdoValueTransferTracker, BlockUploadWithCrcCarriesTheCrcOfTheRewrittenValue) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Channel ch;
    const can::Frame end = block_upload(ch, c, true, true);
    EXPECT_EQ(crc_of(end), crc16_xmodem(c.surface_bytes()));
    EXPECT_NE(crc_of(end), crc16_xmodem(c.local_bytes()));
  }
}

TEST(SdoValueTransferTracker, BlockUploadWithoutCrcLeavesTheCrcFieldAlone) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    const std::uint16_t sent = crc16_xmodem(c.local_bytes());
    Channel no_client_crc;
    EXPECT_EQ(crc_of(block_upload(no_client_crc, c, false, true)), sent);
    Channel no_server_crc;
    EXPECT_EQ(crc_of(block_upload(no_server_crc, c, true, false)), sent);
  }
}

TEST(SdoValueTransferTracker, BlockUploadAnsweredBySegmentedOrExpeditedUploadIsFollowed) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    // Protocol switch threshold: the server answers with the SDO upload protocol.
    Channel segmented;
    segmented.pass(initiate_block_upload(c.mux, true, 127, 16));
    segmented.pass_reply(
        segmented_upload_response(kLocalNode, c.mux, static_cast<std::uint32_t>(c.size)));
    segmented.pass(upload_segment_request(false));
    can::Frame segment = upload_segment(false, c.local_bytes(), true);
    EXPECT_EQ(segmented.reply(segment), ValueRewrite::rewritten);
    expect_data(segment, c.surface_bytes());
    EXPECT_TRUE(segmented.tracker.idle());

    Channel expedited;
    expedited.pass(initiate_block_upload(c.mux, true, 127, 16));
    can::Frame up = upload_response(kLocalNode, c.mux, c.local_bytes());
    EXPECT_EQ(expedited.reply(up), ValueRewrite::rewritten);
    EXPECT_EQ(c.size == 1 ? up.data[4] : read_u32(up, 4), c.surface);
    EXPECT_TRUE(expedited.tracker.idle());
  }
}

// Values naming an id with no counterpart: a surface id no node of this module has (72) on the way
// down, a local node the module does not map (40) on the way up. Every mode: forwarded
// byte-for-byte, reported no_counterpart (the gateway counts it), a block CRC untouched.
TEST(SdoValueTransferTracker, ValuesWithoutCounterpartPassUnchangedInEveryMode) {
  const Family cases[] = {
      {"1028h EMCY consumer", {0x1028, 9}, 0x80 + 40, 0x80 + 72, 4},
      {"1200h sub3 client node", {0x1200, 3}, 40, 72, 1},
      {"1280h sub3 server node", {0x1280, 3}, 40, 72, 1},
  };
  for (const Family& c : cases) {
    SCOPED_TRACE(c.name);
    const auto down_bytes = c.surface_bytes();  // as the master sends them
    const auto up_bytes = c.local_bytes();      // as the node sends them
    auto unmapped = [](ValueRewrite r) { EXPECT_EQ(r, ValueRewrite::no_counterpart); };

    Channel expedited;
    can::Frame down = download_request(kSurfaceNode, c.mux, down_bytes);
    can::Frame before = down;
    unmapped(expedited.send(down));
    EXPECT_EQ(down, before);
    expedited.pass_reply(download_response(kLocalNode, c.mux));
    expedited.pass(upload_request(kSurfaceNode, c.mux));
    can::Frame up = upload_response(kLocalNode, c.mux, up_bytes);
    before = up;
    unmapped(expedited.reply(up));
    EXPECT_EQ(up, before);

    Channel segmented;
    segmented.pass(initiate_segmented_download(c.mux, static_cast<std::uint32_t>(c.size)));
    segmented.pass_reply(download_response(kLocalNode, c.mux));
    can::Frame segment = download_segment(false, down_bytes, true);
    before = segment;
    unmapped(segmented.send(segment));
    EXPECT_EQ(segment, before);
    segmented.pass_reply(download_segment_response(false));
    segmented.pass(upload_request(kSurfaceNode, c.mux));
    segmented.pass_reply(
        segmented_upload_response(kLocalNode, c.mux, static_cast<std::uint32_t>(c.size)));
    segmented.pass(upload_segment_request(false));
    segment = upload_segment(false, up_bytes, true);
    before = segment;
    unmapped(segmented.reply(segment));
    EXPECT_EQ(segment, before);

    Channel block;
    block.pass(initiate_block_download(c.mux, true, static_cast<std::uint32_t>(c.size)));
    block.pass_reply(block_download_initiated(c.mux, true));
    segment = block_segment(true, 1, down_bytes, true);
    before = segment;
    unmapped(block.send(segment));
    EXPECT_EQ(segment, before);
    block.pass_reply(block_ack(false, 1));
    block.pass(block_end(true, c.size, crc16_xmodem(down_bytes)));  // CRC untouched
    block.pass_reply(response(0xA1));
    block.pass(initiate_block_upload(c.mux, true));
    block.pass_reply(block_upload_initiated(c.mux, true, static_cast<std::uint32_t>(c.size)));
    block.pass(start_block_upload());
    segment = block_segment(false, 1, up_bytes, true);
    before = segment;
    unmapped(block.reply(segment));
    EXPECT_EQ(segment, before);
    block.pass(block_ack(true, 1));
    block.pass_reply(block_end(false, c.size, crc16_xmodem(up_bytes)));
    EXPECT_TRUE(block.tracker.idle());
  }
}

// --- confirmed writes: what the node now holds (the gateway's 1017h hook) ----------------------

TEST(SdoValueTransferTracker, AConfirmedExpeditedDownloadIsReportedOnce) {
  const Multiplexer producer{0x1017, 0};
  Channel ch;
  can::Frame write = download_request(kSurfaceNode, producer, std::array<std::uint8_t, 2>{200, 0});
  ch.pass(write);
  EXPECT_FALSE(ch.tracker.confirmed_write());  // not before the node said so
  can::Frame ok = download_response(kLocalNode, producer);
  ch.pass_reply(ok);
  ASSERT_TRUE(ch.tracker.confirmed_write());
  EXPECT_EQ(*ch.tracker.confirmed_write(), (ConfirmedWrite{producer, 200, 2}));
  ch.pass(upload_request(kSurfaceNode, producer));  // the next frame clears it
  EXPECT_FALSE(ch.tracker.confirmed_write());

  // An abort, a response naming another object, a late duplicate response: nothing confirmed.
  ch.pass(download_request(kSurfaceNode, producer, std::array<std::uint8_t, 2>{0x2C, 0x01}));
  ch.pass_reply(response(0x80, producer, 0x06090030));
  EXPECT_FALSE(ch.tracker.confirmed_write());
  ch.pass(download_request(kSurfaceNode, producer, std::array<std::uint8_t, 2>{0x2C, 0x01}));
  ch.pass_reply(download_response(kLocalNode, {0x1018, 0}));
  EXPECT_FALSE(ch.tracker.confirmed_write());
  ch.pass_reply(download_response(kLocalNode, producer));
  EXPECT_FALSE(ch.tracker.confirmed_write());
  // A 4-byte write without size indicated, and a write of a listed object (the local value).
  ch.pass(request(0x22, producer, 0x000003E8));
  ch.pass_reply(download_response(kLocalNode, producer));
  ASSERT_TRUE(ch.tracker.confirmed_write());
  EXPECT_EQ(ch.tracker.confirmed_write()->value, 1000u);
  EXPECT_EQ(ch.tracker.confirmed_write()->size, 4);
  can::Frame emcy = download_request(kSurfaceNode, {0x1014, 0}, le(0xA5));
  EXPECT_EQ(ch.send(emcy), ValueRewrite::rewritten);
  ch.pass_reply(download_response(kLocalNode, {0x1014, 0}));
  ASSERT_TRUE(ch.tracker.confirmed_write());
  EXPECT_EQ(ch.tracker.confirmed_write()->value, 0x85u);
}

// --- unlisted transfers: never touched, their segments never read as commands ------------------

// A block download segment with seqno 0x23 whose bytes are those of an expedited download of
// 1800h sub 1 with surface COB-ID 0x400001A5: a tracker reading it as a command would rewrite it.
constexpr std::array<std::uint8_t, 7> kLooksLikeTpdoDownload = {0x00, 0x18, 0x01, 0xA5,
                                                                0x01, 0x00, 0x40};
// A block upload segment with seqno 0x43: an expedited upload response of 1200h sub 1 (0x605).
constexpr std::array<std::uint8_t, 7> kLooksLikeSdoServerUpload = {0x00, 0x12, 0x01, 0x05,
                                                                   0x06, 0x00, 0x00};

TEST(SdoValueTransferTracker, TheCraftedSegmentsWouldBeRewrittenIfReadAsCommands) {
  // What makes the bit-exact tests below meaningful.
  Channel ch;
  can::Frame download = block_segment(true, 0x23, kLooksLikeTpdoDownload, false);
  EXPECT_EQ(ch.send(download), ValueRewrite::rewritten);
  can::Frame upload = block_segment(false, 0x43, kLooksLikeSdoServerUpload, false);
  EXPECT_EQ(ch.reply(upload), ValueRewrite::rewritten);
}

TEST(SdoValueTransferTracker, UnlistedBlockDownloadOf32KiBPassesBitExact) {
  constexpr std::size_t kSize = 32 * 1024;
  constexpr std::uint8_t kBlockSize = 127;
  // Segment k (0-based) of the transfer goes as seqno k % 127 + 1 unless a sub-block is repeated;
  // every segment's data looks like an expedited download of a listed object.
  std::vector<std::uint8_t> data(kSize);
  for (std::size_t at = 0; at < kSize; at += kSegmentBytes) {
    for (std::size_t i = 0; i < kSegmentBytes && at + i < kSize; ++i) {
      data[at + i] = kLooksLikeTpdoDownload[i];
    }
  }
  const std::size_t segments = (kSize + kSegmentBytes - 1) / kSegmentBytes;
  Channel ch;
  const Multiplexer domain{0x2000, 0};
  ch.pass(initiate_block_download(domain, true, kSize));
  ch.pass_reply(block_download_initiated(domain, true, kBlockSize));
  std::size_t next = 0;  // first segment not yet acknowledged
  int sub_blocks = 0;
  while (next < segments) {
    const std::size_t count = std::min<std::size_t>(kBlockSize, segments - next);
    for (std::size_t s = 0; s < count; ++s) {
      const std::size_t at = (next + s) * kSegmentBytes;
      const std::size_t length = std::min(kSegmentBytes, kSize - at);
      ch.pass(block_segment(true, static_cast<std::uint8_t>(s + 1),
                            std::span(data).subspan(at, length), next + s + 1 == segments));
    }
    // The third sub-block loses segment 101: the server acknowledges 100, the client repeats.
    const std::size_t acked = ++sub_blocks == 3 ? 100 : count;
    ch.pass_reply(block_ack(false, static_cast<std::uint8_t>(acked), kBlockSize));
    next += acked;
  }
  const std::size_t last_length = kSize - (segments - 1) * kSegmentBytes;
  ch.pass(block_end(true, last_length, crc16_xmodem(data)));
  ch.pass_reply(response(0xA1));
  EXPECT_TRUE(ch.tracker.idle());
  // Afterwards the same bytes are a command again.
  can::Frame expedited = block_segment(true, 0x23, kLooksLikeTpdoDownload, false);
  EXPECT_EQ(ch.send(expedited), ValueRewrite::rewritten);
}

TEST(SdoValueTransferTracker, UnlistedBlockUploadPassesBitExact) {
  constexpr std::size_t kSize = 4096;
  std::vector<std::uint8_t> data(kSize);
  for (std::size_t at = 0; at < kSize; ++at) {
    data[at] = kLooksLikeSdoServerUpload[at % kSegmentBytes];
  }
  const std::size_t segments = (kSize + kSegmentBytes - 1) / kSegmentBytes;
  Channel ch;
  const Multiplexer domain{0x1F50, 1};
  ch.pass(initiate_block_upload(domain, true, 127));
  ch.pass_reply(block_upload_initiated(domain, true, kSize));
  ch.pass(start_block_upload());
  std::size_t next = 0;
  while (next < segments) {
    const std::size_t count = std::min<std::size_t>(127, segments - next);
    for (std::size_t s = 0; s < count; ++s) {
      const std::size_t at = (next + s) * kSegmentBytes;
      ch.pass_reply(block_segment(false, static_cast<std::uint8_t>(s + 1),
                                  std::span(data).subspan(at, std::min(kSegmentBytes, kSize - at)),
                                  next + s + 1 == segments));
    }
    ch.pass(block_ack(true, static_cast<std::uint8_t>(count)));
    next += count;
  }
  ch.pass_reply(block_end(false, kSize - (segments - 1) * kSegmentBytes, crc16_xmodem(data)));
  ch.pass(request(0xA1));
  EXPECT_TRUE(ch.tracker.idle());
}

TEST(SdoValueTransferTracker, UnlistedSegmentedUploadPassesBitExact) {
  Channel ch;
  // A string whose segments carry bytes shaped like an expedited upload response of 1200h sub 1.
  const Multiplexer name{0x1008, 0};
  ch.pass(upload_request(kSurfaceNode, name));
  ch.pass_reply(segmented_upload_response(kLocalNode, name, 21));
  bool toggle = false;
  for (int s = 0; s < 3; ++s) {
    ch.pass(upload_segment_request(toggle));
    ch.pass_reply(upload_segment(toggle, kLooksLikeSdoServerUpload, s == 2));
    toggle = !toggle;
  }
  EXPECT_TRUE(ch.tracker.idle());
  // A 4-byte value that reads like a COB-ID, of an object that is not listed (vendor id).
  const Multiplexer vendor{0x1018, 1};
  ch.pass(upload_request(kSurfaceNode, vendor));
  ch.pass_reply(segmented_upload_response(kLocalNode, vendor, 4));
  ch.pass(upload_segment_request(false));
  ch.pass_reply(upload_segment(false, le(0x605), true));
  // And the download of one.
  ch.pass(initiate_segmented_download(vendor, 4));
  ch.pass_reply(download_response(kLocalNode, vendor));
  ch.pass(download_segment(false, le(0x625), true));
  ch.pass_reply(download_segment_response(false));
  EXPECT_TRUE(ch.tracker.idle());
}

// --- aborts, restarts, odd frames --------------------------------------------------------------

TEST(SdoValueTransferTracker, AbortEitherWayEndsTheTransfer) {
  const Multiplexer tpdo{0x1800, 1};
  // Client abort inside a download sub-block (exactly 0x80): the next frame is a command again.
  Channel client;
  client.pass(initiate_block_download({0x2000, 0}, true, 1000));
  client.pass_reply(block_download_initiated({0x2000, 0}, true));
  client.pass(block_segment(true, 1, kLooksLikeTpdoDownload, false));
  client.pass(abort_request(kSurfaceNode, {0x2000, 0}, 0x05040000));
  EXPECT_TRUE(client.tracker.idle());
  can::Frame expedited = block_segment(true, 0x23, kLooksLikeTpdoDownload, false);
  EXPECT_EQ(client.send(expedited), ValueRewrite::rewritten);

  // Server abort inside an upload sub-block.
  Channel server;
  server.pass(initiate_block_upload(tpdo, true));
  server.pass_reply(block_upload_initiated(tpdo, true, 4));
  server.pass(start_block_upload());
  server.pass_reply(abort_response(kLocalNode, tpdo, 0x08000000));
  EXPECT_TRUE(server.tracker.idle());

  // An aborted segmented download: a download segment afterwards is not its value.
  Channel segmented;
  segmented.pass(initiate_segmented_download(tpdo, 4));
  segmented.pass_reply(download_response(kLocalNode, tpdo));
  segmented.pass_reply(abort_response(kLocalNode, tpdo, 0x06010000));
  segmented.pass(download_segment(false, le(0x400001A5u), true));
  EXPECT_TRUE(segmented.tracker.idle());

  // A server abort during a block download ends its sub-block: the in-flight segments are read
  // as the server, now idle, reads them.
  Channel mid;
  mid.pass(initiate_block_download({0x2000, 0}, true, 1000));
  mid.pass_reply(block_download_initiated({0x2000, 0}, true));
  mid.pass_reply(abort_response(kLocalNode, {0x2000, 0}, 0x05040000));
  EXPECT_TRUE(mid.tracker.idle());
}

TEST(SdoValueTransferTracker, ANewInitiateRestartsTracking) {
  const Family& tpdo = kFamilies[7];
  // Mid segmented download of an unlisted object, a segmented download of 1800h sub 1.
  Channel ch;
  ch.pass(initiate_segmented_download({0x2000, 0}, 100));
  ch.pass_reply(download_response(kLocalNode, {0x2000, 0}));
  ch.pass(download_segment(false, kLooksLikeTpdoDownload, false));
  ch.pass(initiate_segmented_download(tpdo.mux, 4));
  ch.pass_reply(download_response(kLocalNode, tpdo.mux));
  can::Frame segment = download_segment(false, tpdo.surface_bytes(), true);
  EXPECT_EQ(ch.send(segment), ValueRewrite::rewritten);
  expect_data(segment, tpdo.local_bytes());

  // Mid block upload of an unlisted object (the client's frames are commands), an expedited
  // download, then a block download of a listed one.
  Channel block;
  block.pass(initiate_block_upload({0x2000, 0}, true));
  block.pass_reply(block_upload_initiated({0x2000, 0}, true, 1000));
  block.pass(start_block_upload());
  block.pass_reply(block_segment(false, 1, kLooksLikeSdoServerUpload, false));
  can::Frame expedited = download_request(kSurfaceNode, tpdo.mux, tpdo.surface_bytes());
  EXPECT_EQ(block.send(expedited), ValueRewrite::rewritten);
  EXPECT_EQ(read_u32(expedited, 4), tpdo.local);
  EXPECT_TRUE(block.tracker.idle());
  EXPECT_EQ(crc_of(block_download(block, tpdo, true, true, 4)), crc16_xmodem(tpdo.local_bytes()));

  // Inside a download sub-block a frame shaped like an initiate is a segment, not a restart.
  Channel sub_block;
  sub_block.pass(initiate_block_download({0x2000, 0}, true, 1000));
  sub_block.pass_reply(block_download_initiated({0x2000, 0}, true));
  const can::Frame lookalike = initiate_block_download(tpdo.mux, true, 4);  // 0xC6: c, seqno 0x46
  sub_block.pass(lookalike);
  EXPECT_FALSE(sub_block.tracker.idle());
}

TEST(SdoValueTransferTracker, ARepeatedSubBlockIsRewrittenAgainAndTheCrcFollowsTheLastCopy) {
  const Family& c = kFamilies[0];
  Channel ch;
  ch.pass(initiate_block_download(c.mux, true, 4));
  ch.pass_reply(block_download_initiated(c.mux, true));
  for (int attempt = 0; attempt < 2; ++attempt) {
    can::Frame segment = block_segment(true, 1, c.surface_bytes(), true);
    EXPECT_EQ(ch.send(segment), ValueRewrite::rewritten);
    expect_data(segment, c.local_bytes());
    // First time the segment is lost: acknowledged with 0, the client repeats it.
    ch.pass_reply(block_ack(false, static_cast<std::uint8_t>(attempt)));
  }
  can::Frame end = block_end(true, 4, crc16_xmodem(c.surface_bytes()));
  EXPECT_EQ(ch.send(end), ValueRewrite::rewritten);
  EXPECT_EQ(crc_of(end), crc16_xmodem(c.local_bytes()));
}

TEST(SdoValueTransferTracker, AWrongCrcStaysWrongByTheSameAmount) {
  const Family& c = kFamilies[5];
  Channel ch;
  ch.pass(initiate_block_download(c.mux, true, 4));
  ch.pass_reply(block_download_initiated(c.mux, true));
  can::Frame segment = block_segment(true, 1, c.surface_bytes(), true);
  EXPECT_EQ(ch.send(segment), ValueRewrite::rewritten);
  ch.pass_reply(block_ack(false, 1));
  const std::uint16_t corruption = 0x0101;
  can::Frame end = block_end(true, 4, crc16_xmodem(c.surface_bytes()) ^ corruption);
  EXPECT_EQ(ch.send(end), ValueRewrite::rewritten);
  EXPECT_EQ(crc_of(end), crc16_xmodem(c.local_bytes()) ^ corruption);  // the node still refuses
}

TEST(SdoValueTransferTracker, EdgeNodeIdsFlagsAndExtendedIds) {
  // local 1 -> surface 127, local 31 -> surface 1, local 127 -> surface 31.
  const std::map<NodeId, NodeId> edges = {{1, 127}, {31, 1}, {127, 31}};
  auto with_edges = [&] {
    Channel ch;
    ch.to_surface = node_map(edges);
    ch.to_local = node_map(inverse(edges));
    return ch;
  };
  const Family cases[] = {
      {"TPDO1 of node 1", {0x1800, 1}, 0x181, 0x1FF, 4},
      {"TPDO1 of node 31, invalid", {0x1800, 1}, 0x8000019Fu, 0x80000181u, 4},
      {"RPDO4 of node 127, both flags", {0x1403, 1}, 0xC000057Fu, 0xC000051Fu, 4},
      {"EMCY of node 127", {0x1014, 0}, 0xFF, 0x9F, 4},
      {"SDO client rx of node 1", {0x1280, 2}, 0x581, 0x5FF, 4},
      {"server node 127", {0x1280, 3}, 127, 31, 1},
      {"server node 1", {0x1280, 3}, 1, 127, 1},
      {"consumer of node 127", {0x1016, 127}, 0x007F03E8u, 0x001F03E8u, 4},
      {"consumer of node 31", {0x1016, 2}, 0x001F03E8u, 0x000103E8u, 4},
  };
  for (const Family& c : cases) {
    SCOPED_TRACE(c.name);
    Channel seg_up = with_edges();
    seg_up.pass(upload_request(kSurfaceNode, c.mux));
    seg_up.pass_reply(
        segmented_upload_response(kLocalNode, c.mux, static_cast<std::uint32_t>(c.size)));
    seg_up.pass(upload_segment_request(false));
    can::Frame segment = upload_segment(false, c.local_bytes(), true);
    EXPECT_EQ(seg_up.reply(segment), ValueRewrite::rewritten);
    expect_data(segment, c.surface_bytes());

    Channel block_down = with_edges();
    EXPECT_EQ(crc_of(block_download(block_down, c, true, true, std::nullopt)),
              crc16_xmodem(c.local_bytes()));
    Channel block_up = with_edges();
    EXPECT_EQ(crc_of(block_upload(block_up, c, true, true)), crc16_xmodem(c.surface_bytes()));
  }

  // 29-bit COB-IDs (bit 29) are network-wide: unchanged, and so is the CRC.
  for (const std::uint32_t extended : {0x20000185u, 0xA0000185u, 0x3FFFFFFFu}) {
    SCOPED_TRACE(extended);
    Channel ch = with_edges();
    const Multiplexer tpdo{0x1800, 1};
    ch.pass(initiate_block_download(tpdo, true, 4));
    ch.pass_reply(block_download_initiated(tpdo, true));
    ch.pass(block_segment(true, 1, le(extended), true));
    ch.pass_reply(block_ack(false, 1));
    ch.pass(block_end(true, 4, crc16_xmodem(le(extended))));
    ch.pass(initiate_segmented_download(tpdo, 4));
    ch.pass_reply(download_response(kLocalNode, tpdo));
    ch.pass(download_segment(false, le(extended), true));
  }

  // An id the map does not know: reported, forwarded unchanged, CRC untouched.
  Channel ch = with_edges();
  const Multiplexer rpdo{0x1400, 1};
  ch.pass(initiate_block_upload(rpdo, true));
  ch.pass_reply(block_upload_initiated(rpdo, true, 4));
  ch.pass(start_block_upload());
  can::Frame unknown = block_segment(false, 1, le(0x205), true);
  const can::Frame before = unknown;
  EXPECT_EQ(ch.reply(unknown), ValueRewrite::no_counterpart);
  EXPECT_EQ(unknown, before);
  ch.pass(block_ack(true, 1));
  ch.pass_reply(block_end(false, 4, crc16_xmodem(le(0x205))));
}

TEST(SdoValueTransferTracker, TransfersThatDoNotCarryExactlyTheValueAreNotRewritten) {
  const Family& c = kFamilies[7];  // 1800h sub 1
  const std::vector<std::uint8_t> surface = c.surface_bytes();
  // Size indicated 2 (the node refuses it): nothing rewritten.
  Channel small;
  small.pass(initiate_segmented_download(c.mux, 2));
  small.pass_reply(download_response(kLocalNode, c.mux));
  small.pass(download_segment(false, std::span(surface).first(2), true));
  // Size not indicated, but the segment holds 5 bytes.
  Channel five;
  five.pass(request(0x20, c.mux));
  five.pass_reply(download_response(kLocalNode, c.mux));
  const std::array<std::uint8_t, 5> bytes = {0xA5, 0x01, 0x00, 0x40, 0x00};
  five.pass(download_segment(false, bytes, true));
  // A value spread over two segments.
  Channel split;
  split.pass(request(0x20, c.mux));
  split.pass_reply(download_response(kLocalNode, c.mux));
  split.pass(download_segment(false, std::span(surface).first(2), false));
  split.pass_reply(download_segment_response(false));
  split.pass(download_segment(true, std::span(surface).subspan(2), true));
  // Block download indicating 8 bytes.
  Channel block;
  block.pass(initiate_block_download(c.mux, true, 8));
  block.pass_reply(block_download_initiated(c.mux, true));
  block.pass(block_segment(true, 1, surface, false));
  block.pass(block_segment(true, 2, std::array<std::uint8_t, 1>{0}, true));
  block.pass_reply(block_ack(false, 2));
  block.pass(block_end(true, 1, 0x1234));
  // Without an indicated size, a second sub-block whose seqno 1 is the last segment: not the
  // start of the data (the node refuses the length).
  Channel later;
  later.pass(initiate_block_download(c.mux, true, std::nullopt));
  later.pass_reply(block_download_initiated(c.mux, true, 2));
  later.pass(block_segment(true, 1, kLooksLikeTpdoDownload, false));
  later.pass(block_segment(true, 2, kLooksLikeTpdoDownload, false));
  later.pass_reply(block_ack(false, 2, 2));
  later.pass(block_segment(true, 1, surface, true));
  later.pass_reply(block_ack(false, 1, 2));
  later.pass(block_end(true, 4, 0x1234));
  EXPECT_TRUE(later.tracker.idle());
  // A response naming another object than the request.
  Channel other;
  other.pass(upload_request(kSurfaceNode, c.mux));
  other.pass_reply(segmented_upload_response(kLocalNode, {0x1000, 0}, 4));
  other.pass(upload_segment_request(false));
  other.pass_reply(upload_segment(false, c.local_bytes(), true));
  // A segmented upload response nobody asked for.
  Channel unasked;
  unasked.pass_reply(segmented_upload_response(kLocalNode, c.mux, 4));
  unasked.pass(upload_segment_request(false));
  unasked.pass_reply(upload_segment(false, c.local_bytes(), true));
}

TEST(SdoValueTransferTracker, NonSdoFramesAndResetDoNotDisturb) {
  Channel ch;
  ch.pass(initiate_block_download({0x2000, 0}, true, 1000));
  ch.pass_reply(block_download_initiated({0x2000, 0}, true));
  // A short frame on the channel is not SDO: untouched, and the sub-block goes on.
  ch.pass(can::Frame::standard(request_cob(kSurfaceNode), {0x80}));
  ch.pass(block_segment(true, 0x23, kLooksLikeTpdoDownload, false));
  EXPECT_FALSE(ch.tracker.idle());
  ch.tracker.reset();
  EXPECT_TRUE(ch.tracker.idle());
  // After a reset the next frame is an initiate.
  const Family& c = kFamilies[9];
  can::Frame expedited = download_request(kSurfaceNode, c.mux, c.surface_bytes());
  EXPECT_EQ(ch.send(expedited), ValueRewrite::rewritten);
  EXPECT_EQ(read_u32(expedited, 4), c.local);
}

TEST(SdoValueTransferTracker, RandomTrafficOnlyEverChangesValueOrCrcBytes) {
  // Both directions interleaved, byte 0 drawn mostly from real commands and listed objects
  // favoured, so every phase is reached; whatever the tracker does, it never touches the
  // identifier, length or byte 0, and reports every change it makes.
  std::mt19937 rng(20240601);
  const std::uint8_t commands[] = {0x21, 0x23, 0x2F, 0x40, 0x41, 0x43, 0x4F, 0x60, 0x00,
                                   0x07, 0x0D, 0x20, 0x30, 0x80, 0xA0, 0xA4, 0xA2, 0xA3,
                                   0xA1, 0xC0, 0xC2, 0xC6, 0xC1, 0xCD, 0x81, 0x01, 0x02};
  const Multiplexer muxes[] = {{0x1800, 1}, {0x1280, 3}, {0x1016, 5}, {0x2000, 0}};
  Channel ch;
  int rewrites = 0;
  for (int i = 0; i < 200000; ++i) {
    can::Frame f = (rng() & 1) != 0 ? request(0) : response(0);
    for (auto& b : f.data) b = static_cast<std::uint8_t>(rng());
    if (rng() % 4 != 0) f.data[0] = commands[rng() % std::size(commands)];
    if (rng() % 2 != 0) write_multiplexer(f, muxes[rng() % std::size(muxes)]);
    if (rng() % 3 == 0) f.data[4] = static_cast<std::uint8_t>(rng() % 8);
    const can::Frame before = f;
    const bool is_request = f.id == request_cob(kSurfaceNode);
    const ValueRewrite result = is_request ? ch.send(f) : ch.reply(f);
    ASSERT_EQ(f.id, before.id);
    ASSERT_EQ(f.len, before.len);
    ASSERT_EQ(f.data[0], before.data[0]);
    if (result == ValueRewrite::rewritten) {
      ++rewrites;
    } else {
      ASSERT_EQ(f, before) << can::to_string(before);
    }
  }
  EXPECT_GT(rewrites, 0);
}

}  // namespace
}  // namespace canbridge::canopen::sdo
