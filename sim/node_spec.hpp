// What a rig file says about a simulated node, a bus and a rig: plain typed options that the rig
// loader fills and validates, and that the node cores are built from.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "canopen/cob_id.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

// The four kinds of device in the seeds (docs/sim-nodes.md describes each).
enum class NodeKind : std::uint8_t {
  microcanopen,  // seeds/002: minimal node, expedited SDO only, 4+4 PDOs
  qd,            // seeds/003 + 001: extended connection set, block SDO, state-change EMCY, loader
  fpga,    // seeds/000: CPU-less node, expedited SDO, fixed PDOs, PDO Packets, node-id command
  cia301,  // a complete CiA 301 device: expedited, segmented and block SDO
};
std::optional<NodeKind> parse_node_kind(std::string_view name);
const char* to_string(NodeKind kind);

// Object 1018h.
struct Identity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::uint32_t serial = 0;
};

// A manufacturer or profile object the rig file adds to the node's dictionary.
struct ObjectSpec {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  DataType type = DataType::unsigned32;
  Access access = Access::rw;
  std::vector<std::uint8_t> value;  // little-endian; a numeric type's exact size
};

// One mapped object of a PDO (CiA 301 mapping entry: index, sub-index, length in bits).
struct PdoMapEntry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::uint8_t bits = 0;  // 8, 16, 24, ... 64; a PDO maps at most 64 bits in all
};

// A transmit or receive PDO: communication parameters (1400h/1800h + n-1) and mapping
// (1600h/1A00h + n-1).
struct PdoSpec {
  unsigned number = 1;  // 1-based
  // Sub 1 without bit 31; nullopt = the kind's default connection set.
  std::optional<std::uint32_t> cob_id;
  bool enabled = true;  // false sets bit 31 of the COB-ID entry
  // 0: acyclic synchronous (on the next SYNC after a change), 1..240: every n-th SYNC,
  // 254/255: event-driven (change of state and event timer).
  std::uint8_t transmission_type = 255;
  std::uint16_t inhibit_100us = 0;   // TPDO: minimum gap between two transmissions
  std::uint16_t event_timer_ms = 0;  // TPDO: periodic transmission, 0 = off
  std::vector<PdoMapEntry> mapping;
};

// Process activity the node generates by itself, so PDOs, PDO Packets and EMCYs happen in rigs
// and in the demo without a script.
struct TrafficSpec {
  enum class Kind : std::uint8_t {
    counter,          // adds `step` to object index:sub every period (wraps at its size)
    pdop_sample,      // sends a `bytes`-long PDO Packet on TPDO `pdo` every period (fpga)
    subsystem_event,  // flags state change of `subsystem` (qd: bit of the Fxxxh EMCY code)
  };
  Kind kind = Kind::counter;
  std::chrono::milliseconds period{100};
  std::uint16_t index = 0;  // counter
  std::uint8_t sub = 0;     // counter
  std::int64_t step = 1;    // counter
  unsigned pdo = 1;         // pdop_sample: TPDO number 1..4
  std::size_t bytes = 256;  // pdop_sample: packet size
  unsigned subsystem = 0;   // subsystem_event: 0..11
};

// docs/pdop.md section 5, the node's side.
struct PdopSpec {
  std::size_t max_packet_bytes = 4096;
  std::chrono::milliseconds fragment_timeout{200};  // RPDOP receiver: gap before discarding
  std::uint8_t window = 4;                          // RPDOP receiver: credit it grants
};

struct EmcySpec {
  std::uint16_t inhibit_100us = 0;         // 1015h
  std::chrono::milliseconds holdoff{100};  // qd: minimum gap between state-change EMCYs
};

// The qd CANopen loader (seeds/003).
struct LoaderSpec {
  // The application in flash at power-on is intact. False models a node whose last download
  // failed: it stays in the loader until a good image is downloaded and started.
  bool application_valid = true;
  // False: the loader starts a valid application by itself after its boot-up (the usual
  // power-on). True: it waits for 1F51h:01 = 1 or an NMT start/enter-pre-operational.
  bool wait_for_command = false;
};

struct NodeSpec {
  NodeKind kind = NodeKind::cia301;
  std::string name;               // for logs and rig files; may be empty
  canopen::NodeId node_id = 1;    // 1..127 (qd and fpga: 1..31)
  std::uint32_t device_type = 0;  // 1000h; 0 = the kind's default
  Identity identity;
  std::uint16_t heartbeat_ms = 1000;  // initial 1017h; 0 disables the heartbeat
  // No NMT master present (seeds/002): enter operational right after boot-up.
  bool auto_start = false;
  std::vector<ObjectSpec> objects;
  std::vector<PdoSpec> tpdos;  // empty = the kind's defaults
  std::vector<PdoSpec> rpdos;
  std::vector<TrafficSpec> traffic;
  PdopSpec pdop;
  EmcySpec emcy;
  LoaderSpec loader;
  std::chrono::milliseconds sdo_timeout{1000};  // segmented/block transfer idle timeout
  std::uint8_t sdo_block_size = 127;            // largest block the server accepts (1..127)
};

// One CAN bus of a rig and the nodes on it.
struct BusSpec {
  std::string name;       // e.g. "probe"
  std::string interface;  // SocketCAN interface (e.g. "vcan2"); empty = virtual bus `name`
  std::vector<NodeSpec> nodes;
};

struct RigSpec {
  std::string name;
  std::string description;
  std::vector<BusSpec> buses;
};

}  // namespace canbridge::sim
