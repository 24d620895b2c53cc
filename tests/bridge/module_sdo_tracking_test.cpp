// The gateway's per-module SDO tracking, driven directly: values naming ids rewritten both ways in
// expedited, segmented and block transfers under each module's own map, ids of other modules left
// alone (counted), one independent channel per node and module, channels that start over when a
// node boots or the link dies, and the SDO requests a dead link withdraws from a bus queue.
#include "bridge/module_sdo_tracking.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <span>
#include <vector>

#include "bridge/bus_write_queue.hpp"
#include "canopen/crc16.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::bridge {
namespace {

using canopen::sdo::Multiplexer;

constexpr std::size_t kModule = 1;  // module id 1: local n <-> surface n + 32 (default map)
constexpr NodeId kNode = 5;         // local id on module 1's bus; surface 37

NodeMap two_modules() {
  NodeMap map;
  EXPECT_TRUE(map.add_module(0, NodeMap::default_pairs(0)).empty());
  EXPECT_TRUE(map.add_module(1, NodeMap::default_pairs(1)).empty());
  return map;
}

std::array<std::uint8_t, 4> le(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

// SDO frames as a module bus carries them (local COB-IDs).
can::Frame sdo(std::uint32_t cob, std::uint8_t byte0, Multiplexer mux = {},
               std::uint32_t value = 0) {
  can::Frame f;
  f.id = cob;
  f.len = 8;
  f.data[0] = byte0;
  canopen::sdo::write_multiplexer(f, mux);
  canopen::sdo::write_u32(f, 4, value);
  return f;
}
can::Frame request(std::uint8_t byte0, Multiplexer mux = {}, std::uint32_t value = 0,
                   NodeId node = kNode) {
  return sdo(canopen::sdo::request_cob(node), byte0, mux, value);
}
can::Frame response(std::uint8_t byte0, Multiplexer mux = {}, std::uint32_t value = 0,
                    NodeId node = kNode) {
  return sdo(canopen::sdo::response_cob(node), byte0, mux, value);
}
// A segment: byte0, then the value's `size` bytes.
can::Frame segment(can::Frame f, std::uint32_t value, std::size_t size) {
  std::fill(f.data.begin() + 1, f.data.end(), 0);
  const auto b = le(value);
  std::copy_n(b.begin(), size, f.data.begin() + 1);
  return f;
}
std::uint32_t segment_value(const can::Frame& f, std::size_t size) {
  std::uint32_t v = 0;
  for (std::size_t i = 0; i < size; ++i) v |= std::uint32_t{f.data[1 + i]} << (8 * i);
  return v;
}
std::uint8_t unused(std::size_t size) {
  return static_cast<std::uint8_t>(7 - size);
}
std::uint16_t crc_of(std::uint32_t value, std::size_t size) {
  const auto b = le(value);
  return canopen::crc16_xmodem(std::span(b.data(), size));
}

// An object whose value names an id: as the node holds it and as the master sees it.
struct Family {
  const char* name;
  Multiplexer mux;
  std::uint32_t local;
  std::uint32_t surface;
  std::size_t size;
};
const Family kFamilies[] = {
    {"1028h sub1 EMCY consumer", {0x1028, 1}, 0x85, 0xA5, 4},
    {"1200h sub3 client node", {0x1200, 3}, 7, 39, 1},
    {"1400h sub1 RPDO1", {0x1400, 1}, 0x205, 0x225, 4},
    {"1800h sub1 TPDO1, no RTR", {0x1800, 1}, 0x40000185u, 0x400001A5u, 4},
    {"1014h EMCY", {0x1014, 0}, 0x85, 0xA5, 4},
    {"1016h sub1 consumer", {0x1016, 1}, 0x000700C8u, 0x002700C8u, 4},
};

// The gateway's two directions around the core: what the master sends becomes what the node
// receives, what the node answers becomes what the master reads.
struct Gateway {
  NodeMap map = two_modules();
  ModuleSdoTracking sdo{map};

  can::Frame to_bus(can::Frame f, std::size_t m = kModule) {
    sdo.to_bus(m, f);
    return f;
  }
  // `f` as read on module m's bus; returns it as the surface sees it (COB-ID translated).
  can::Frame from_bus(const can::Frame& f, std::size_t m = kModule) {
    can::Frame out = f;
    out.id = map.surface_cob_of(m, f.id);
    heartbeat = sdo.from_bus(m, f, out);
    return out;
  }
  std::optional<ModuleSdoTracking::HeartbeatWrite> heartbeat;
};

std::uint8_t expedited_download(std::size_t size) {
  return static_cast<std::uint8_t>(0x23 | (4 - size) << 2);
}
std::uint8_t expedited_upload(std::size_t size) {
  return static_cast<std::uint8_t>(0x43 | (4 - size) << 2);
}

TEST(ModuleSdoTracking, ExpeditedValuesAreRewrittenBothWays) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Gateway g;
    const can::Frame written = g.to_bus(request(expedited_download(c.size), c.mux, c.surface));
    EXPECT_EQ(canopen::sdo::read_u32(written, 4), c.local);
    g.from_bus(response(0x60, c.mux));
    g.to_bus(request(0x40, c.mux));
    const can::Frame read = g.from_bus(response(expedited_upload(c.size), c.mux, c.local));
    EXPECT_EQ(read.id, 0x580u + 37);
    EXPECT_EQ(canopen::sdo::read_u32(read, 4), c.surface);
    EXPECT_EQ(g.sdo.counters().values_rewritten, 2u);
    EXPECT_EQ(g.sdo.counters().values_unmapped, 0u);
  }
}

TEST(ModuleSdoTracking, SegmentedValuesAreRewrittenBothWays) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Gateway g;
    g.to_bus(request(0x21, c.mux, static_cast<std::uint32_t>(c.size)));  // initiate, size given
    g.from_bus(response(0x60, c.mux));
    const auto last = static_cast<std::uint8_t>(unused(c.size) << 1 | 1);
    const can::Frame down = g.to_bus(segment(request(last), c.surface, c.size));
    EXPECT_EQ(segment_value(down, c.size), c.local);
    g.from_bus(response(0x20));

    g.to_bus(request(0x40, c.mux));
    g.from_bus(response(0x41, c.mux, static_cast<std::uint32_t>(c.size)));  // segmented upload
    g.to_bus(request(0x60));
    const can::Frame up = g.from_bus(segment(response(last), c.local, c.size));
    EXPECT_EQ(segment_value(up, c.size), c.surface);
    EXPECT_EQ(g.sdo.counters().values_rewritten, 2u);
  }
}

TEST(ModuleSdoTracking, BlockValuesAreRewrittenBothWaysWithTheirCrc) {
  for (const Family& c : kFamilies) {
    SCOPED_TRACE(c.name);
    Gateway g;
    const auto end = static_cast<std::uint8_t>(0xC1 | unused(c.size) << 2);
    // Download with CRC: initiate (cc, size), server agrees (sc), one sub-block of one segment.
    g.to_bus(request(0xC6, c.mux, static_cast<std::uint32_t>(c.size)));
    g.from_bus(response(0xA4, c.mux, 127));
    const can::Frame down = g.to_bus(segment(request(0x81), c.surface, c.size));
    EXPECT_EQ(segment_value(down, c.size), c.local);
    can::Frame ack = response(0xA2);  // the segment with seqno 1 arrived: end phase next
    ack.data[1] = 1;
    ack.data[2] = 127;
    g.from_bus(ack);
    can::Frame end_request = request(end);
    end_request.data[1] = static_cast<std::uint8_t>(crc_of(c.surface, c.size));
    end_request.data[2] = static_cast<std::uint8_t>(crc_of(c.surface, c.size) >> 8);
    const can::Frame crc_sent = g.to_bus(end_request);
    EXPECT_EQ(crc_sent.data[1] | crc_sent.data[2] << 8, crc_of(c.local, c.size));
    g.from_bus(response(0xA1));

    // Upload with CRC.
    can::Frame initiate = request(0xA4, c.mux);
    initiate.data[4] = 127;
    initiate.data[5] = 0;
    g.to_bus(initiate);
    g.from_bus(response(0xC6, c.mux, static_cast<std::uint32_t>(c.size)));
    g.to_bus(request(0xA3));
    const can::Frame up = g.from_bus(segment(response(0x81), c.local, c.size));
    EXPECT_EQ(segment_value(up, c.size), c.surface);
    can::Frame client_ack = request(0xA2);
    client_ack.data[1] = 1;
    client_ack.data[2] = 127;
    g.to_bus(client_ack);
    can::Frame end_response = response(end);
    end_response.data[1] = static_cast<std::uint8_t>(crc_of(c.local, c.size));
    end_response.data[2] = static_cast<std::uint8_t>(crc_of(c.local, c.size) >> 8);
    const can::Frame crc_read = g.from_bus(end_response);
    EXPECT_EQ(crc_read.data[1] | crc_read.data[2] << 8, crc_of(c.surface, c.size));
    g.to_bus(request(0xA1));
  }
}

// A value may only name the module's own ids: surface node 5 is module 0's, local node 40 has no
// surface id. Both cross unchanged and are counted.
TEST(ModuleSdoTracking, IdsWithoutCounterpartInTheModuleAreCountedAndForwardedUnchanged) {
  Gateway g;
  const can::Frame other_module = request(0x23, {0x1014, 0}, 0x85);
  EXPECT_EQ(g.to_bus(other_module), other_module);
  g.from_bus(response(0x60, {0x1014, 0}));
  g.to_bus(request(0x40, {0x1016, 1}));
  const can::Frame unmapped = response(0x43, {0x1016, 1}, 0x002800C8u);  // producer node 40
  const can::Frame read = g.from_bus(unmapped);
  EXPECT_EQ(read.id, 0x580u + 37);
  EXPECT_TRUE(std::equal(read.data.begin(), read.data.end(), unmapped.data.begin()));
  EXPECT_EQ(g.sdo.counters().values_unmapped, 2u);
  EXPECT_EQ(g.sdo.counters().values_rewritten, 0u);

  // Surface node 38 is module 1's local node 6: rewritten.
  const can::Frame own = g.to_bus(request(0x23, {0x1014, 0}, 0x80 + 38));
  EXPECT_EQ(canopen::sdo::read_u32(own, 4), 0x80u + 6);
  EXPECT_EQ(g.sdo.counters().values_rewritten, 1u);
}

// Each node of each module has its own channel: frames of one never move another's phase.
TEST(ModuleSdoTracking, ChannelsOfNodesAndModulesAreIndependent) {
  Gateway g;
  const Multiplexer emcy{0x1014, 0};
  g.to_bus(request(0x21, emcy, 4));  // module 1 node 5: segmented download open
  g.from_bus(response(0x60, emcy));
  // Node 6 of the same module and node 5 of module 0: a whole transfer each, and an abort.
  g.to_bus(request(0x23, emcy, 0xA6, 6));
  g.from_bus(response(0x60, emcy, 0, 6));
  g.to_bus(request(0x80, emcy, 0x08000000, kNode), 0);
  g.from_bus(response(0x80, emcy, 0x08000000, kNode), 0);
  const can::Frame down = g.to_bus(segment(request(0x07), 0xA5, 4));
  EXPECT_EQ(segment_value(down, 4), 0x85u) << "node 5's segment after the others' frames";
}

// The heartbeat period a node confirmed writing reaches the node table; a master's write on the
// module bus (followed, not rewritten) counts as well; a refused write does not.
TEST(ModuleSdoTracking, AConfirmedHeartbeatProducerTimeIsReported) {
  Gateway g;
  const Multiplexer producer{0x1017, 0};
  const can::Frame write = request(0x2B, producer, 500);
  EXPECT_EQ(g.to_bus(write), write);
  g.from_bus(response(0x60, producer));
  ASSERT_TRUE(g.heartbeat);
  EXPECT_EQ(*g.heartbeat,
            (ModuleSdoTracking::HeartbeatWrite{kNode, std::chrono::milliseconds(500)}));

  g.to_bus(request(0x2B, producer, 200));
  g.from_bus(response(0x80, producer, 0x06090030));  // aborted by the node
  EXPECT_FALSE(g.heartbeat);

  g.from_bus(request(0x2B, producer, 250, 7));  // a master on module 1's bus, to node 7
  g.from_bus(response(0x60, producer, 0, 7));
  ASSERT_TRUE(g.heartbeat);
  EXPECT_EQ(g.heartbeat->node, 7);
  EXPECT_EQ(g.heartbeat->period, std::chrono::milliseconds(250));
  EXPECT_EQ(g.sdo.counters().values_rewritten, 0u);
}

NodeEvent event(NodeEvent::Kind kind, NodeId local, NodeId previous_local = 0) {
  NodeEvent e;
  e.kind = kind;
  e.module_index = kModule;
  e.local = local;
  e.previous_local = previous_local;
  return e;
}

// A boot-up (or rename) ends the node's transfer; other events do not.
TEST(ModuleSdoTracking, ANodeThatBootsStartsWithNoTransferOpen) {
  Gateway g;
  const Multiplexer emcy{0x1014, 0};
  auto open_download = [&] {
    g.to_bus(request(0x21, emcy, 4));
    g.from_bus(response(0x60, emcy));
  };
  const can::Frame value_segment = segment(request(0x07), 0xA5, 4);
  open_download();
  g.sdo.on_node_event(event(NodeEvent::Kind::state_changed, kNode));
  EXPECT_EQ(segment_value(g.to_bus(value_segment), 4), 0x85u);

  open_download();
  g.sdo.on_node_event(event(NodeEvent::Kind::booted, kNode));
  EXPECT_EQ(g.to_bus(value_segment), value_segment);

  open_download();  // renamed from 5 to 9: the old id's channel starts over too
  g.sdo.on_node_event(event(NodeEvent::Kind::renamed, 9, kNode));
  EXPECT_EQ(g.to_bus(value_segment), value_segment);
}

// The link died: the master saw its transfers aborted. The segment of an open transfer is no
// longer read as one, and the SDO requests still waiting for the bus are withdrawn, never
// written; other frames keep their order.
TEST(ModuleSdoTracking, ALinkDeathWithdrawsWaitingRequestsAndEndsEveryTransfer) {
  Gateway g;
  const Multiplexer emcy{0x1014, 0};
  g.to_bus(request(0x21, emcy, 4));
  g.from_bus(response(0x60, emcy));

  BusWriteQueue queue({});
  std::vector<can::Frame> written;
  const can::Frame nmt_start = [] {
    can::Frame f;
    f.id = 0;
    f.len = 2;
    f.data[0] = 1;
    return f;
  }();
  const can::Frame heartbeat_write = g.to_bus(request(0x2B, {0x1017, 0}, 100, 6));
  const can::Frame answer = response(0x60, {0x1017, 0}, 0, 6);  // not a request: stays
  for (const can::Frame& f : {nmt_start, heartbeat_write, answer}) {
    ASSERT_TRUE(queue.offer(std::span(&f, 1), BusWriteQueue::Lane::reliable, 0, written));
  }

  g.sdo.on_link_dead();
  g.sdo.withdrew(queue.withdraw_single_frames(ModuleSdoTracking::withdrawn_at_link_loss));
  queue.take(10, written);
  ASSERT_EQ(written.size(), 2u);
  EXPECT_EQ(written[0], nmt_start);
  EXPECT_EQ(written[1], answer);
  EXPECT_EQ(g.sdo.counters().requests_withdrawn, 1u);

  const can::Frame value_segment = segment(request(0x07), 0xA5, 4);
  EXPECT_EQ(g.to_bus(value_segment), value_segment);
  EXPECT_FALSE(ModuleSdoTracking::withdrawn_at_link_loss(response(0x43, emcy, 0x85)));
}

// The map is read live: a node renamed in the gateway's map speaks its new ids at once.
TEST(ModuleSdoTracking, ANodeMovedInTheLiveMapIsRewrittenUnderItsNewIds) {
  Gateway g;
  ASSERT_TRUE(g.map.move(kModule, kNode, 40, 100));  // local 40, surface 100
  const can::Frame written = g.to_bus(request(0x23, {0x1014, 0}, 0x80 + 100, 40));
  EXPECT_EQ(canopen::sdo::read_u32(written, 4), 0x80u + 40);
  const can::Frame read = g.from_bus(response(0x60, {0x1014, 0}, 0, 40));
  EXPECT_EQ(read.id, 0x580u + 100);
  const can::Frame old_id = request(0x23, {0x1014, 0}, 0x80 + 37, 40);  // surface 37 is free now
  EXPECT_EQ(g.to_bus(old_id), old_id);
  EXPECT_EQ(g.sdo.counters().values_unmapped, 1u);
}

}  // namespace
}  // namespace canbridge::bridge
