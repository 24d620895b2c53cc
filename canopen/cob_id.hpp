// CiA 301 predefined connection set: function codes and node-id arithmetic of 11-bit COB-IDs.
#pragma once

#include <cstdint>
#include <optional>

namespace canbridge::canopen {

using NodeId = std::uint8_t;  // 1..127 on a CiA 301 bus; 0 addresses all nodes in NMT

inline constexpr NodeId kMaxNodeId = 127;

// Base COB-IDs of the predefined connection set (CiA 301 table 76/77).
namespace cob {
inline constexpr std::uint16_t nmt = 0x000;
inline constexpr std::uint16_t sync = 0x080;
inline constexpr std::uint16_t emcy = 0x080;  // + node id (1..127)
inline constexpr std::uint16_t time = 0x100;
inline constexpr std::uint16_t tpdo1 = 0x180;
inline constexpr std::uint16_t rpdo1 = 0x200;
inline constexpr std::uint16_t tpdo2 = 0x280;
inline constexpr std::uint16_t rpdo2 = 0x300;
inline constexpr std::uint16_t tpdo3 = 0x380;
inline constexpr std::uint16_t rpdo3 = 0x400;
inline constexpr std::uint16_t tpdo4 = 0x480;
inline constexpr std::uint16_t rpdo4 = 0x500;
inline constexpr std::uint16_t sdo_tx = 0x580;     // server -> client (response), + node id
inline constexpr std::uint16_t sdo_rx = 0x600;     // client -> server (request), + node id
inline constexpr std::uint16_t heartbeat = 0x700;  // NMT error control, + node id
inline constexpr std::uint16_t lss_master = 0x7E5;
inline constexpr std::uint16_t lss_slave = 0x7E4;
}  // namespace cob

// NMT command specifiers (byte 0 of a COB-ID 0 frame).
namespace nmt {
inline constexpr std::uint8_t start = 0x01;
inline constexpr std::uint8_t stop = 0x02;
inline constexpr std::uint8_t enter_pre_operational = 0x80;
inline constexpr std::uint8_t reset_node = 0x81;
inline constexpr std::uint8_t reset_communication = 0x82;
}  // namespace nmt

// Heartbeat / boot-up state byte values.
enum class NmtState : std::uint8_t {
  boot_up = 0x00,
  stopped = 0x04,
  operational = 0x05,
  pre_operational = 0x7F,
  // Not a heartbeat byte (the toggle bit is never part of a state): the bridge's mark for a node
  // heard by other frames (an SDO answer, an EMCY) whose state no heartbeat or boot-up has told.
  unknown = 0xFF,
};

// "operational", ...: the state byte of a heartbeat (toggle bit stripped) for logs.
constexpr const char* nmt_state_name(std::uint32_t state) {
  switch (state) {
    case 0x00:
      return "boot-up";
    case 0x04:
      return "stopped";
    case 0x05:
      return "operational";
    case 0x7F:
      return "pre-operational";
    default:
      return "unknown";
  }
}

// A node-addressed COB-ID split into its function base (e.g. 0x580) and node id, or nullopt for
// COB-IDs that carry no node id (NMT, SYNC, TIME, LSS, unused ranges).
struct NodeAddress {
  std::uint16_t function_base;
  NodeId node;
};

constexpr std::optional<NodeAddress> split_predefined(std::uint32_t cob_id) {
  if (cob_id > 0x7FF) return std::nullopt;
  const auto base = static_cast<std::uint16_t>(cob_id & 0x780);
  const auto node = static_cast<NodeId>(cob_id & 0x7F);
  if (node == 0) return std::nullopt;  // NMT, SYNC, TIME and the bare bases carry no node
  switch (base) {
    case cob::emcy:
    case cob::tpdo1:
    case cob::rpdo1:
    case cob::tpdo2:
    case cob::rpdo2:
    case cob::tpdo3:
    case cob::rpdo3:
    case cob::tpdo4:
    case cob::rpdo4:
    case cob::sdo_tx:
    case cob::sdo_rx:
      return NodeAddress{base, node};
    case cob::heartbeat:
      // 0x780..0x7FF hold LSS (0x7E4/0x7E5) and reserved ids: not node-addressed.
      return NodeAddress{base, node};
    default:
      return std::nullopt;  // 0x100 + n (TIME range) is not node-addressed
  }
}

}  // namespace canbridge::canopen
