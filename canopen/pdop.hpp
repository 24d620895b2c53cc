// PDO Packets (docs/pdop.md): identifier layout, fragments of a packet and acknowledgement frames,
// as pure functions shared by the simulated node and the gateway.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"

namespace canbridge::canopen::pdop {

inline constexpr std::uint16_t kAckBase = 0x680;  // + node id: function code 13 (section 4.1)
inline constexpr NodeId kMaxNode = 31;            // the node id has 5 bits left (section 1)
inline constexpr std::size_t kFragmentBytes = 8;
// 65,535 fragments: the acknowledgement counts fragments in a u16.
inline constexpr std::size_t kMaxPacketBytes = 65535 * kFragmentBytes;
inline constexpr std::uint8_t kAckLength = 5;

// The fields of a PDOP identifier: function code (bits 10..7), t (6), c (5), node id (4..0).
struct FragmentId {
  std::uint8_t function_code = 0;  // 3, 5, 7, 9: TPDO1..4; 4, 6, 8, 10: RPDO1..4
  bool toggle = false;
  bool continued = false;
  NodeId node = 0;

  friend bool operator==(const FragmentId&, const FragmentId&) = default;
};

constexpr std::uint32_t encode(const FragmentId& id) {
  return (std::uint32_t{id.function_code} & 0x0Fu) << 7 | (id.toggle ? 0x40u : 0u) |
         (id.continued ? 0x20u : 0u) | (std::uint32_t{id.node} & 0x1Fu);
}

constexpr FragmentId decode(std::uint32_t cob_id) {
  return FragmentId{static_cast<std::uint8_t>((cob_id >> 7) & 0x0Fu), (cob_id & 0x40u) != 0,
                    (cob_id & 0x20u) != 0, static_cast<NodeId>(cob_id & 0x1Fu)};
}

// COB-ID base of TPDO/RPDO `number` (1..4) in the predefined connection set: 0x180, 0x280, ...
// and 0x200, 0x300, ...; 0 for any other number, which no PDO has.
constexpr std::uint16_t tpdo_base(unsigned number) {
  return number >= 1 && number <= 4 ? static_cast<std::uint16_t>(0x180 + 0x100 * (number - 1)) : 0;
}
constexpr std::uint16_t rpdo_base(unsigned number) {
  return number >= 1 && number <= 4 ? static_cast<std::uint16_t>(0x200 + 0x100 * (number - 1)) : 0;
}

// The PDO number (1..4) a function code stands for, or nullopt when it is no TPDO/RPDO code.
constexpr std::optional<unsigned> tpdo_number(std::uint8_t function_code) {
  if (function_code < 3 || function_code > 9 || function_code % 2 == 0) return std::nullopt;
  return (function_code - 1u) / 2u;
}
constexpr std::optional<unsigned> rpdo_number(std::uint8_t function_code) {
  if (function_code < 4 || function_code > 10 || function_code % 2 != 0) return std::nullopt;
  return (function_code - 2u) / 2u;
}

// The fragments of `packet` in order (docs/pdop.md section 2). Empty when the packet is empty or
// longer than kMaxPacketBytes, `pdo_base` is none of the eight PDO bases or `node` is outside
// 1..kMaxNode: there is no frame sequence that would carry it.
std::vector<can::Frame> fragment(std::uint16_t pdo_base, NodeId node,
                                 std::span<const std::uint8_t> packet);

// Sender abort (section 4.4): a zero-length data frame with c = 0 (and t = 0).
can::Frame abort_frame(std::uint16_t pdo_base, NodeId node);

constexpr std::uint16_t ack_cob_id(NodeId node) {
  return static_cast<std::uint16_t>(kAckBase + (node & 0x1Fu));
}

enum class AckStatus : std::uint8_t {
  in_progress = 0,
  complete = 1,
  // Receiver aborts: the node has discarded the packet.
  toggle_error = 0x80,
  oversize = 0x81,
  out_of_memory = 0x82,  // a real node's FIFO overflow; the simulated node never sends it
  timeout = 0x83,
  short_fragment = 0x84,
  sender_abort = 0x85,  // confirms the sender's own abort frame
};

constexpr bool is_abort(AckStatus status) {
  return static_cast<std::uint8_t>(status) >= 0x80;
}

// Acknowledgement data (section 4.1): [rpdo, status, received lo, received hi, credit].
struct Ack {
  std::uint8_t rpdo = 1;  // 1..4
  AckStatus status = AckStatus::in_progress;
  std::uint16_t received = 0;  // fragments of the packet accepted so far
  std::uint8_t credit = 0;     // further fragments the node can take now

  friend bool operator==(const Ack&, const Ack&) = default;
};

can::Frame encode_ack(NodeId node, const Ack& ack);
// nullopt unless a standard data frame of exactly 5 bytes on 0x681..0x69F naming RPDO 1..4. The
// node is the low 5 bits of the frame's id.
std::optional<Ack> decode_ack(const can::Frame& frame);

// Acknowledgement request (section 4.3): a remote frame on the acknowledgement COB-ID. Its DLC is
// the acknowledgement's 5, as CAN asks of remote frames so that simultaneous requests match.
can::Frame ack_request(NodeId node);

}  // namespace canbridge::canopen::pdop
