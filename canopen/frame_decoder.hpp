// Every CAN frame of a CANopen bus explained in one line of CANopen terms (seed 000's testbench
// "CANopen Logger"): NMT, SYNC, TIME, EMCY, heartbeat, loader boot-up, SDO, PDO, PDO Packets and
// LSS, for `canbridge dump` and logs. Pure: frames in, text out; the only state is what a reader
// of the bus must remember to name a frame (SDO block phases, PDO Packets being assembled).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::canopen {

enum class FrameKind : std::uint8_t {
  nmt,        // COB-ID 0: node control, and the fpga node-id commands (docs/nmt-node-id.md)
  sync,       // 0x080
  time,       // 0x100
  emcy,       // 0x080 + n
  heartbeat,  // 0x700 + n: heartbeat, boot-up, node guarding
  loader,     // qd: the loader's boot-up on 0x720 + n (seed 003)
  sdo,        // 0x600 + n requests, 0x580 + n responses
  pdo,        // TPDO / RPDO
  pdop,       // a PDO Packet fragment or acknowledgement (docs/pdop.md)
  lss,        // 0x7E4 / 0x7E5
  unknown,    // extended, error frames and COB-IDs no service uses
};

const char* to_string(FrameKind kind);
std::optional<FrameKind> parse_frame_kind(std::string_view name);
// "nmt sync time emcy heartbeat loader sdo pdo pdop lss unknown".
std::string frame_kind_names();

// How a bus lays out node-addressed COB-IDs (docs/id-profiles.md; the names of routing's
// IdProfile, which this layer cannot see): pdop buses carry t/c in bits 6-5 of PDO COB-IDs, qd
// buses slots, and both address nodes 1..31 only.
enum class BusLayout : std::uint8_t { cia301, pdop, qd };
std::optional<BusLayout> parse_bus_layout(std::string_view name);

struct DecodedFrame {
  FrameKind kind = FrameKind::unknown;
  std::optional<NodeId> node;  // the node the frame is from or to, when it names one
  std::string text;            // e.g. "SDO 5 upload request 1018:01"
};

class FrameDecoder {
 public:
  // Frames of `module` are read with `layout` (default cia301, also for module 0, the surface).
  void set_layout(unsigned module, BusLayout layout);
  DecodedFrame decode(const can::Frame& frame, unsigned module = 0);

 private:
  struct SdoChannel {
    sdo::Multiplexer mux;         // of the transfer the channel runs
    bool block_download = false;  // client frames are block segments
    bool block_upload = false;    // server frames are block segments
    unsigned final_seq = 0;       // seqno of the last block segment: a lower ack resends
  };
  struct Packet {
    std::vector<std::uint8_t> bytes;
    bool toggle = false;  // expected t of the next fragment
    bool open = false;
  };
  using ChannelKey = std::pair<unsigned, NodeId>;                  // module, node
  using PacketKey = std::tuple<unsigned, NodeId, unsigned, bool>;  // module, node, pdo, tpdo

  BusLayout layout(unsigned module) const;
  DecodedFrame decode_sdo(const can::Frame& frame, unsigned module, NodeId node, bool request);
  DecodedFrame decode_pdop(const can::Frame& frame, unsigned module);

  std::map<unsigned, BusLayout> layouts_;
  std::map<ChannelKey, SdoChannel> sdo_;
  std::map<PacketKey, Packet> packets_;
};

// What `canbridge dump --module --node --kind` keeps; unset fields match everything.
struct FrameFilter {
  std::optional<unsigned> module;
  std::optional<NodeId> node;
  std::vector<FrameKind> kinds;  // empty: every kind
  bool matches(const DecodedFrame& decoded, unsigned module_of_frame) const;
};

}  // namespace canbridge::canopen
