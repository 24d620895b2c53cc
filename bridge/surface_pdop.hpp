// The surface's decisions on the PDO Packet messages a gateway sends (docs/pdop.md), without I/O:
// whether a packet may go on the surface bus and as which fragments, and what status a master
// sees for an RPDOP outcome. The surface only carries the fragments and statuses.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "canopen/cob_id.hpp"
#include "canopen/pdop.hpp"

namespace canbridge::bridge {

// What a TPDOP packet from a gateway comes to on the surface bus.
struct PdopPacketToBus {
  enum class Verdict : std::uint8_t {
    to_bus,         // `fragments` go on the bus, whole and in order
    not_its_own,    // a node outside the gateway's claims: dropped, counted as such
    cannot_be_put,  // a module it did not announce, no TPDO, a node out of range, no bytes
  };
  Verdict verdict = Verdict::cannot_be_put;
  std::uint32_t cob_id = 0;  // the TPDO's COB-ID of the node (not_its_own: for the count)
  std::vector<can::Frame> fragments;
};

// `announced`: whether the packet's module is one the gateway announced; `speaks_for`: whether
// the gateway's claims cover a surface node. A packet goes on the bus as the node sent it, under
// its surface id, so a master on the surface bus sees PDOP unchanged.
PdopPacketToBus surface_pdop_packet(const v1::PdopPacket& packet, bool announced,
                                    const std::function<bool(canopen::NodeId)>& speaks_for);

// The status a master sees for the gateway's outcome of its RPDOP packet: the node's own abort
// status where the node answered, the nearest PDOP status otherwise (a node that could not take
// the packet at all: out of memory).
canopen::pdop::AckStatus rpdop_ack_status(const v1::RpdopOutcome& outcome);

}  // namespace canbridge::bridge
