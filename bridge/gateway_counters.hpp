// What a gateway counts, in one snapshot: the session, the outbox, translation and every module
// bus, for its stats line, its RoleStatistics and its tests.
#pragma once

#include <array>
#include <cstdint>

#include "backbone/serial_framing.hpp"
#include "backbone/session.hpp"
#include "bridge/bus_write_queue.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/gateway_pdop_work.hpp"
#include "bridge/gateway_remote.hpp"
#include "routing/cob_id_translator.hpp"

namespace canbridge::bridge {

struct GatewayCounters {
  backbone::SessionCounters session;
  OutboxCounters outbox;
  DropCounters translation{};
  std::uint64_t from_buses = 0;       // frames read on module buses
  std::uint64_t to_buses = 0;         // frames handed to module buses
  std::uint64_t frames_received = 0;  // frames decoded from the backbone
  std::uint64_t bus_refused = 0;      // frames for module buses dropped (bus_drops says why)
  // Frames that waited for room in a module bus's transmit queue, and drops by reason
  // (BusWriteQueue::Drop), all module buses together.
  std::uint64_t bus_waited = 0;
  std::uint64_t bus_waiting_peak = 0;
  std::array<std::uint64_t, BusWriteQueue::kDropReasons> bus_drops{};
  std::uint64_t backbone_pauses = 0;     // the surface's payloads went unread: a bus was backed up
  std::uint64_t malformed_payloads = 0;  // payloads that are not a valid, consistent batch
  std::uint64_t unknown_module = 0;      // batches naming a module this gateway does not serve
  std::uint64_t process_lost_on_line = 0;  // process frames the surface sent that never arrived
  backbone::DeframerCounters framing{};    // CRC-framed links (serial), all links so far
  std::uint64_t echoes_dropped = 0;        // frames this gateway wrote, read back from a bus
  // Frames in the reliable payloads the session gave up on, by backbone::ReliableDrop (the
  // session counts payloads, which hold many frames): too old before they were ever sent, for a
  // surface process that is gone, and too old after they were sent (the surface may have them;
  // not a drop count).
  std::uint64_t session_frames_too_old = 0;
  std::uint64_t session_frames_peer_restart = 0;
  std::uint64_t session_frames_expired_unacked = 0;
  // SDO requests from the surface still waiting for a bus when the link died (the master was
  // told they failed): never written.
  std::uint64_t sdo_requests_withdrawn = 0;
  // SDO values naming COB-IDs or node ids (1200h.., 1400h.., 1800h.., 1014h, 1016h, 1028h)
  // rewritten between bus and surface ids, and those whose id has no counterpart (forwarded
  // unchanged).
  std::uint64_t sdo_values_rewritten = 0;
  std::uint64_t sdo_values_unmapped = 0;
  std::uint64_t node_events = 0;          // node table events queued for the surface
  std::uint64_t node_events_dropped = 0;  // ... dropped: the link was down too long (bounded)
  // Renamed nodes that moved in the live map, and confirmed renames it could not follow
  // (refused commands are counted in translation as rename-refused).
  std::uint64_t nodes_moved = 0;
  std::uint64_t node_moves_refused = 0;
  // PDO Packets (pdop modules with reassembly; docs/pdop.md), as the core counts them.
  GatewayPdopWork::Counters pdop;
  std::uint64_t backbone_tx_bytes = 0;  // bytes written on backbone links, all links so far
  // Services run for the surface (remote access, docs/remote-access.md) and the start-up census
  // (Gateway::start), as the core counts them.
  GatewayRemote::Counters remote;
  // A master's SDO requests refused with 0x08000021: the gateway ran its own transfer with the
  // node.
  std::uint64_t sdo_collisions = 0;
};

}  // namespace canbridge::bridge
