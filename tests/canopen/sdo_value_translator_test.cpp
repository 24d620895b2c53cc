// Values that name COB-IDs or nodes, rewritten inside expedited SDO transfers: every listed
// object, both directions, flag bits kept, ordinary objects and other services untouched.
#include "canopen/sdo_value_translator.hpp"

#include <gtest/gtest.h>

#include <array>

namespace canbridge::canopen::sdo {
namespace {

// The default map of module 1: local node n (1..31) is surface node n + 32.
IdMapping to_surface() {
  return {[](std::uint32_t cob) -> std::optional<std::uint32_t> {
            auto a = canopen::split_predefined(cob);
            if (!a || a->node > 31) return std::nullopt;
            return a->function_base + a->node + 32u;
          },
          [](NodeId n) -> std::optional<NodeId> {
            if (n == 0 || n > 31) return std::nullopt;
            return static_cast<NodeId>(n + 32);
          }};
}
IdMapping to_local() {
  return {[](std::uint32_t cob) -> std::optional<std::uint32_t> {
            auto a = canopen::split_predefined(cob);
            if (!a || a->node < 33 || a->node > 63) return std::nullopt;
            return a->function_base + a->node - 32u;
          },
          [](NodeId n) -> std::optional<NodeId> {
            if (n < 33 || n > 63) return std::nullopt;
            return static_cast<NodeId>(n - 32);
          }};
}

std::array<std::uint8_t, 4> le_bytes(std::uint32_t v) {
  return {static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
          static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)};
}

// An expedited upload response from local node 5 carrying `value` for `mux`.
can::Frame upload_of(Multiplexer mux, std::uint32_t value, std::size_t size = 4) {
  const auto bytes = le_bytes(value);
  return upload_response(5, mux, std::span<const std::uint8_t>(bytes.data(), size));
}
can::Frame download_of(Multiplexer mux, std::uint32_t value, std::size_t size = 4) {
  const auto bytes = le_bytes(value);
  return download_request(37, mux, std::span<const std::uint8_t>(bytes.data(), size));
}

TEST(SdoValueKind, EveryListedObjectAndNothingElse) {
  EXPECT_EQ(value_kind({0x1200, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1200, 2}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x127F, 2}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1200, 0}), ValueKind::none);
  EXPECT_EQ(value_kind({0x1200, 3}), ValueKind::node_id);  // the client's node id
  EXPECT_EQ(value_kind({0x127F, 3}), ValueKind::node_id);
  EXPECT_EQ(value_kind({0x1200, 4}), ValueKind::none);
  EXPECT_EQ(value_kind({0x1280, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x12FF, 2}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1280, 3}), ValueKind::node_id);
  EXPECT_EQ(value_kind({0x1400, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x15FF, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1400, 2}), ValueKind::none);
  EXPECT_EQ(value_kind({0x1800, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x19FF, 1}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1A00, 1}), ValueKind::none);  // a PDO mapping entry, not a COB-ID
  EXPECT_EQ(value_kind({0x1014, 0}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1016, 1}), ValueKind::node_in_16_23);
  EXPECT_EQ(value_kind({0x1016, 127}), ValueKind::node_in_16_23);
  EXPECT_EQ(value_kind({0x1016, 0}), ValueKind::none);    // the entry count
  EXPECT_EQ(value_kind({0x1028, 1}), ValueKind::cob_id);  // EMCY consumer: node 1's EMCY
  EXPECT_EQ(value_kind({0x1028, 127}), ValueKind::cob_id);
  EXPECT_EQ(value_kind({0x1028, 0}), ValueKind::none);  // the entry count
  EXPECT_EQ(value_kind({0x1028, 128}), ValueKind::none);
  EXPECT_EQ(value_kind({0x1029, 1}), ValueKind::none);  // error behaviour
  EXPECT_EQ(value_kind({0x1005, 0}), ValueKind::none);  // SYNC: the same on every bus
  EXPECT_EQ(value_kind({0x1012, 0}), ValueKind::none);  // TIME
  EXPECT_EQ(value_kind({0x1017, 0}), ValueKind::none);
}

TEST(SdoValueTranslator, UploadResponsesOfCobIdObjectsSpeakSurfaceIds) {
  struct Case {
    Multiplexer mux;
    std::uint32_t local;
    std::uint32_t surface;
  };
  const Case cases[] = {
      {{0x1200, 1}, 0x605, 0x625},              // SDO server: client -> server
      {{0x1200, 2}, 0x585, 0x5A5},              // SDO server: server -> client
      {{0x1280, 1}, 0x601, 0x621},              // SDO client: to its server
      {{0x1400, 1}, 0x205, 0x225},              // RPDO1
      {{0x1403, 1}, 0x80000505u, 0x80000525u},  // RPDO4, invalid flag kept
      {{0x1800, 1}, 0x40000185u, 0x400001A5u},  // TPDO1, no-RTR flag kept
      {{0x1801, 1}, 0xC0000285u, 0xC00002A5u},  // TPDO2, both flags
      {{0x1014, 0}, 0x85, 0xA5},                // EMCY
      {{0x1016, 1}, 0x000700C8u, 0x002700C8u},  // heartbeat consumer: node 7, 200 ms
      {{0x1016, 3}, 0x001F0064u, 0x003F0064u},  // node 31, 100 ms
  };
  for (const Case& c : cases) {
    can::Frame f = upload_of(c.mux, c.local);
    EXPECT_EQ(rewrite_response(f, to_surface()), ValueRewrite::rewritten)
        << std::hex << c.mux.index << ":" << int(c.mux.sub);
    EXPECT_EQ(read_u32(f, 4), c.surface) << std::hex << c.mux.index << ":" << int(c.mux.sub);
    EXPECT_EQ(read_multiplexer(f), c.mux);
    EXPECT_EQ(f.data[0], upload_of(c.mux, c.local).data[0]);  // command byte untouched
  }
}

TEST(SdoValueTranslator, DownloadsFromTheSurfaceReachTheNodeInItsOwnIds) {
  can::Frame tpdo = download_of({0x1800, 1}, 0x400001A5u);
  EXPECT_EQ(rewrite_request(tpdo, to_local()), ValueRewrite::rewritten);
  EXPECT_EQ(read_u32(tpdo, 4), 0x40000185u);
  can::Frame consumer = download_of({0x1016, 2}, 0x002201F4u);  // surface node 34, 500 ms
  EXPECT_EQ(rewrite_request(consumer, to_local()), ValueRewrite::rewritten);
  EXPECT_EQ(read_u32(consumer, 4), 0x000201F4u);
  can::Frame server_node = download_of({0x1280, 3}, 40, 1);  // UNSIGNED8
  EXPECT_EQ(rewrite_request(server_node, to_local()), ValueRewrite::rewritten);
  EXPECT_EQ(server_node.data[4], 8);
  EXPECT_EQ(server_node.data[5], 0);
}

TEST(SdoValueTranslator, OrdinaryObjectsOtherServicesAndUnmappableIdsAreLeftAlone) {
  can::Frame device_type = upload_of({0x1000, 0}, 0x00000191);
  EXPECT_EQ(rewrite_response(device_type, to_surface()), ValueRewrite::unchanged);
  EXPECT_EQ(read_u32(device_type, 4), 0x00000191u);
  // A segmented upload initiation names a size, not a value.
  can::Frame segmented = segmented_upload_response(5, {0x1800, 1}, 4);
  EXPECT_EQ(rewrite_response(segmented, to_surface()), ValueRewrite::unchanged);
  EXPECT_EQ(read_u32(segmented, 4), 4u);
  // An upload request carries no value; a download response neither.
  can::Frame request = upload_request(37, {0x1800, 1});
  EXPECT_EQ(rewrite_request(request, to_local()), ValueRewrite::unchanged);
  can::Frame ack = download_response(5, {0x1800, 1});
  EXPECT_EQ(rewrite_response(ack, to_surface()), ValueRewrite::unchanged);
  // 29-bit COB-IDs, unused consumer entries: unchanged and fine.
  can::Frame extended = upload_of({0x1800, 1}, 0x20000185u);
  EXPECT_EQ(rewrite_response(extended, to_surface()), ValueRewrite::unchanged);
  EXPECT_EQ(read_u32(extended, 4), 0x20000185u);
  can::Frame unused = upload_of({0x1016, 4}, 0x00000000u);
  EXPECT_EQ(rewrite_response(unused, to_surface()), ValueRewrite::unchanged);
  // A COB-ID that has no counterpart (node 40 is not on this module bus): forwarded as is, said.
  can::Frame foreign = upload_of({0x1400, 1}, 0x228);
  EXPECT_EQ(rewrite_response(foreign, to_surface()), ValueRewrite::no_counterpart);
  EXPECT_EQ(read_u32(foreign, 4), 0x228u);
  // A non-SDO-shaped frame (short) is not touched.
  can::Frame short_frame = can::Frame::standard(0x585, {0x43, 0x00, 0x18, 0x01});
  EXPECT_EQ(rewrite_response(short_frame, to_surface()), ValueRewrite::unchanged);
}

TEST(SdoValueTranslator, AWrongSizeIsLeftForTheNodeToRefuse) {
  // A 2-byte download into a COB-ID entry: the node aborts with a length error; the bridge does
  // not reinterpret half a value.
  can::Frame f = download_of({0x1800, 1}, 0x01A5, 2);
  EXPECT_EQ(rewrite_request(f, to_local()), ValueRewrite::unchanged);
  EXPECT_EQ(read_u32(f, 4) & 0xFFFF, 0x01A5u);
}

}  // namespace
}  // namespace canbridge::canopen::sdo
