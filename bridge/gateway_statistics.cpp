#include "bridge/gateway_statistics.hpp"

#include <fmt/format.h>

#include "bridge/counter_text.hpp"
#include "bridge/role_statistics_fill.hpp"

namespace canbridge::bridge {

RoleStatistics gateway_statistics(const GatewayStatsSnapshot& snapshot) {
  const GatewayCounters& c = snapshot.counters;
  RoleStatistics s;
  s.role = "gateway";
  s.name = snapshot.name;
  s.buses = snapshot.buses;
  BackboneStatistics& b = s.backbone;
  b.peers_up = snapshot.connected ? 1 : 0;
  b.peers_known = 1;
  copy_stream_counters(c, b);
  b.tx_bytes = c.backbone_tx_bytes;
  add_link_reads_and_writes(snapshot.links, b);
  b.unacked = snapshot.unacked;
  if (snapshot.connected && snapshot.round_trip) b.round_trip = *snapshot.round_trip;
  for (std::size_t r = 0; r < kDropReasonCount; ++r) {
    s.drops.push_back(
        {std::string("untranslatable-") + to_string(static_cast<DropReason>(r)), c.translation[r]});
  }
  add_bus_write_drops(c, s.drops);
  s.drops.push_back({"conflated", c.outbox.conflated});
  s.drops.push_back({"process-dropped", c.outbox.process_dropped});
  s.drops.push_back({"reliable-refused", c.outbox.reliable_refused});
  // Frames, each counted once: dropped while queued (outbox) or in a payload never sent
  // (session); the session's own counts are payloads.
  s.drops.push_back({"reliable-too-old", c.outbox.reliable_too_old + c.session_frames_too_old});
  s.drops.push_back(
      {"reliable-peer-restart", c.outbox.discarded_peer_restart + c.session_frames_peer_restart});
  s.drops.push_back({"process-lost-on-line", c.process_lost_on_line});
  s.drops.push_back({"malformed-payload", c.malformed_payloads + c.session.malformed});
  s.drops.push_back({"unknown-module", c.unknown_module});
  s.drops.push_back({"node-events-dropped", c.node_events_dropped});
  const NodeCounts& n = snapshot.nodes;
  s.nodes = {n.operational, n.pre_operational, n.stopped, n.in_loader, n.lost, n.unknown};
  return s;
}

std::string gateway_stats_line(const GatewayStatsSnapshot& snapshot) {
  const GatewayCounters& c = snapshot.counters;
  std::uint64_t dropped = 0;
  for (auto d : c.translation) dropped += d;
  std::string s = fmt::format(
      "gateway {}: link {}, bus->backbone {} frames ({} batches), backbone->bus {}, "
      "untranslatable {}, queued {}, conflated {}, process-dropped {}, reliable-refused {}, "
      "reliable sent {} resent {} unacked {}, dead-links {}, refusals {}/{}, malformed {}, "
      "bus-refused {}, echoes-dropped {}, sdo-values rewritten {} unmapped {}, stale-links {}, "
      "reliable dropped too-old {} surface-restart {} expired-unacked {}, "
      "sdo-requests-withdrawn {}",
      snapshot.name, snapshot.connected ? "up" : "down", c.outbox.frames_sent,
      c.outbox.batches_sent, c.to_buses, dropped, snapshot.queued, c.outbox.conflated,
      c.outbox.process_dropped, c.outbox.reliable_refused, c.session.reliable_sent,
      c.session.reliable_resent, snapshot.unacked, c.session.dead_links, c.session.refusals_sent,
      c.session.refusals_received, c.malformed_payloads + c.session.malformed, c.bus_refused,
      c.echoes_dropped, c.sdo_values_rewritten, c.sdo_values_unmapped, c.session.stale_links_closed,
      c.outbox.reliable_too_old + c.session_frames_too_old,
      c.outbox.discarded_peer_restart + c.session_frames_peer_restart,
      c.session_frames_expired_unacked, c.sdo_requests_withdrawn);
  s += fmt::format("; {}, node-events {} dropped {}; backbone-tx-bytes {}; {}",
                   to_string(snapshot.nodes), c.node_events, c.node_events_dropped,
                   c.backbone_tx_bytes, lanes_summary(c.outbox));
  s += fmt::format("; bus-waited {} (peak {}, backbone-pauses {})", c.bus_waited,
                   c.bus_waiting_peak, c.backbone_pauses);
  for (std::size_t r = 0; r < BusWriteQueue::kDropReasons; ++r) {
    if (c.bus_drops[r] != 0) {
      s += fmt::format(" dropped-{} {}", to_string(static_cast<BusWriteQueue::Drop>(r)),
                       c.bus_drops[r]);
    }
  }
  s += fmt::format(
      "; from-buses {} frames-received {} unknown-module {} process-lost-on-line {} "
      "queued-total {} sdo-requests-withdrawn {}; {}",
      c.from_buses, c.frames_received, c.unknown_module, c.process_lost_on_line, c.outbox.queued,
      c.outbox.sdo_requests_withdrawn, session_counters_text(c.session));
  if (snapshot.pdop_active ||
      c.pdop.rpdop_packets != 0) {  // RPDOP packets to no pdop node: refused
    s += fmt::format(
        "; pdop packets {} ({} bytes, {} fragments) discarded {} dropped-frames {} refused {}, "
        "rpdop packets {} complete {} failed {}",
        c.pdop.packets, c.pdop.packet_bytes, c.pdop.fragments, c.pdop.discards,
        snapshot.pdop_dropped_frames, c.pdop.refused, c.pdop.rpdop_packets, c.pdop.rpdop_complete,
        c.pdop.rpdop_failed);
  }
  if (c.remote.requests + c.sdo_collisions + c.remote.duplicates != 0) {
    s += fmt::format(
        "; remote requests {} failed {} cancelled {} duplicates {} waited-for-master {} "
        "sdo-collisions {}",
        c.remote.requests, c.remote.failed, c.remote.cancelled, c.remote.duplicates,
        c.remote.waited_for_master, c.sdo_collisions);
  }
  if (c.remote.census_questions != 0) {
    s += fmt::format("; census questions {} gave-way {} late-answers {}", c.remote.census_questions,
                     c.remote.census_yielded, c.remote.census_late_answers);
  }
  if (c.framing.frames + c.framing.discarded_bytes != 0) {
    s += "; " + framing_counters_text(c.framing);
  }
  for (const BusStatistics& bus : snapshot.buses) {
    s += "; " + bus_counters_text(bus.interface, bus.counters);
  }
  return s;
}

}  // namespace canbridge::bridge
