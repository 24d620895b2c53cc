// What a surface counts, in one snapshot: the sessions, the outboxes, the SDO link guard and its
// bus, for its stats line, its RoleStatistics and its tests.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "backbone/serial_framing.hpp"
#include "backbone/session.hpp"
#include "bridge/bus_write_queue.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/gateway_table.hpp"
#include "bridge/sdo_link_guard.hpp"
#include "bridge/surface_pdop_work.hpp"

namespace canbridge::bridge {

struct SurfaceCounters {
  backbone::SessionCounters session;
  OutboxCounters outbox;                 // summed over the gateways
  std::uint64_t from_bus = 0;            // frames read on the surface bus
  std::uint64_t to_bus = 0;              // frames written to the surface bus
  std::uint64_t frames_received = 0;     // frames decoded from the backbone
  std::uint64_t dropped_no_gateway = 0;  // surface frames while no gateway was ever known
  std::uint64_t dropped_unclaimed = 0;   // surface frames to a node no gateway claims
  std::uint64_t bus_refused = 0;         // frames for the surface bus dropped (bus_drops: why)
  std::uint64_t bus_waited = 0;          // frames that waited for room in its transmit queue
  std::uint64_t bus_waiting_peak = 0;
  std::array<std::uint64_t, BusWriteQueue::kDropReasons> bus_drops{};  // by BusWriteQueue::Drop
  std::uint64_t backbone_pauses = 0;  // the gateways' payloads went unread: the bus was backed up
  std::uint64_t malformed_payloads = 0;    // payloads that are not a valid, consistent batch
  std::uint64_t unknown_module = 0;        // batches for a module the gateway did not announce
  std::uint64_t process_lost_on_line = 0;  // process frames gateways sent that never arrived
  backbone::DeframerCounters framing{};    // CRC-framed links (serial), all links so far
  std::uint64_t echoes_dropped = 0;        // frames the surface wrote, read back from its bus
  std::uint64_t node_events = 0;           // node table events the gateways reported
  // SDO requests never sent because the master got an abort when their link went down: queued
  // ones are in outbox.sdo_requests_withdrawn, these were sent and not yet acknowledged.
  std::uint64_t sdo_requests_withdrawn_unacked = 0;
  // SDO requests whose master the surface answered for itself (aborts, recovered answers) and
  // answers it kept from the master, as the link guard counts them.
  SdoLinkGuard::Counters sdo_guard;
  // Reliable frames for a gateway given up before it acknowledged them, by reason (queued ones
  // and sent ones); SDO requests among them were answered with an abort if still open.
  std::uint64_t reliable_dropped_too_old = 0;  // never sent: the gateway never had them
  std::uint64_t reliable_dropped_gateway_restart = 0;
  // Sent, then too old before an ack came: the gateway may have them (not a drop count; its
  // session's tombstones-received says how many payloads did not arrive).
  std::uint64_t reliable_expired_unacked = 0;
  // PDO Packets (docs/pdop.md).
  SurfacePdopWork::Counters pdop;      // as the core counts them
  std::uint64_t pdop_bus_refused = 0;  // packets refused: more fragments than the bus holds
  // Who may speak (issue 15): hellos refused for who the peer is (a name not configured, an
  // identity not proven), and frames bound gateways sent that are not theirs to send, by reason
  // (NotItsOwn), summed and per gateway (configured names only: bounded).
  std::uint64_t refused_strangers = 0;
  std::array<std::uint64_t, kNotItsOwnReasons> not_its_own{};
  std::vector<std::pair<std::string, std::array<std::uint64_t, kNotItsOwnReasons>>>
      not_its_own_by_gateway;
};

}  // namespace canbridge::bridge
