// The fpga kind's custom NMT command that sets or changes a node id (seeds/000; frame layout in
// docs/nmt-node-id.md): pure encoding and decoding, shared by the simulated node and the bridge.
#pragma once

#include <cstdint>
#include <optional>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/little_endian.hpp"

namespace canbridge::canopen::nmt_node_id {

// Command specifiers in byte 0 of an NMT frame (COB-ID 0). CiA 301 uses 01h, 02h, 80h, 81h and
// 82h; E0h/E1h are unused there, so a standard slave ignores these frames.
inline constexpr std::uint8_t kChange = 0xE0;    // by current node id
inline constexpr std::uint8_t kBySerial = 0xE1;  // by serial number (1018h:04)
inline constexpr NodeId kMaxNodeId = 31;         // the 5-bit node field of the PDOP layout

// `000#E0 cc nn`: the node whose id is cc (1..31) takes id nn (1..31).
struct ChangeNodeId {
  NodeId current = 0;
  NodeId next = 0;
  friend bool operator==(const ChangeNodeId&, const ChangeNodeId&) = default;
};
// `000#E1 nn s0 s1 s2 s3`: the node whose serial number is s (little-endian) takes id nn, whatever
// its id was (also two nodes that share one id can be told apart this way).
struct SetNodeIdBySerial {
  NodeId next = 0;
  std::uint32_t serial = 0;
  friend bool operator==(const SetNodeIdBySerial&, const SetNodeIdBySerial&) = default;
};

inline bool valid_node_id(NodeId id) {
  return id >= 1 && id <= kMaxNodeId;
}

inline can::Frame encode(const ChangeNodeId& c) {
  return can::Frame::standard(cob::nmt, {kChange, c.current, c.next});
}
inline can::Frame encode(const SetNodeIdBySerial& s) {
  can::Frame f = can::Frame::standard(cob::nmt, {kBySerial, s.next, 0, 0, 0, 0});
  store_le(s.serial, std::span(f.data).subspan(2, 4));
  return f;
}

// nullopt unless the frame is exactly the documented layout with valid ids: a malformed command
// must never rename a node.
inline std::optional<ChangeNodeId> decode_change(const can::Frame& f) {
  if (f.id != cob::nmt || f.is_remote() || f.is_extended() || f.len != 3 || f.data[0] != kChange)
    return std::nullopt;
  ChangeNodeId c{f.data[1], f.data[2]};
  if (!valid_node_id(c.current) || !valid_node_id(c.next)) return std::nullopt;
  return c;
}
inline std::optional<SetNodeIdBySerial> decode_by_serial(const can::Frame& f) {
  if (f.id != cob::nmt || f.is_remote() || f.is_extended() || f.len != 6 || f.data[0] != kBySerial)
    return std::nullopt;
  SetNodeIdBySerial s{f.data[1], load_le32(std::span(f.data).subspan(2, 4))};
  if (!valid_node_id(s.next)) return std::nullopt;
  return s;
}

}  // namespace canbridge::canopen::nmt_node_id
