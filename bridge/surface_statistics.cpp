#include "bridge/surface_statistics.hpp"

#include <fmt/format.h>

#include "bridge/counter_text.hpp"
#include "bridge/role_statistics_fill.hpp"

namespace canbridge::bridge {

RoleStatistics surface_statistics(const SurfaceStatsSnapshot& snapshot) {
  const SurfaceCounters& c = snapshot.counters;
  RoleStatistics s;
  s.role = "surface";
  s.name = snapshot.name;
  s.buses.push_back(snapshot.bus);
  BackboneStatistics& b = s.backbone;
  b.peers_up = static_cast<std::uint32_t>(snapshot.gateways_up);
  b.peers_known = static_cast<std::uint32_t>(snapshot.gateways_known);
  b.tx_bytes = snapshot.links.tx_bytes;
  add_link_reads_and_writes(snapshot.links, b);
  copy_stream_counters(c, b);
  b.unacked = snapshot.unacked;
  b.round_trip = snapshot.round_trip;
  add_bus_write_drops(c, s.drops);
  s.drops.push_back({"no-gateway", c.dropped_no_gateway});
  s.drops.push_back({"unclaimed", c.dropped_unclaimed});
  for (std::size_t r = 0; r < kNotItsOwnReasons; ++r) {
    s.drops.push_back(
        {std::string("not-its-own-") + to_string(static_cast<NotItsOwn>(r)), c.not_its_own[r]});
  }
  s.drops.push_back({"conflated", c.outbox.conflated});
  s.drops.push_back({"process-dropped", c.outbox.process_dropped});
  s.drops.push_back({"reliable-refused", c.outbox.reliable_refused});
  s.drops.push_back({"reliable-too-old", c.reliable_dropped_too_old});
  s.drops.push_back({"reliable-peer-restart", c.reliable_dropped_gateway_restart});
  s.drops.push_back({"process-lost-on-line", c.process_lost_on_line});
  s.drops.push_back({"malformed-payload", c.malformed_payloads + c.session.malformed});
  s.drops.push_back({"unknown-module", c.unknown_module});
  s.drops.push_back({"pdop-malformed", c.pdop.malformed});
  s.drops.push_back({"pdop-bus-refused", c.pdop_bus_refused});
  s.sdo_requests = {
      {"aborted-link-down", c.sdo_guard.aborted()},
      {"aborted-given-up", c.sdo_guard.aborted_discarded},
      {"answers-recovered", c.sdo_guard.answers_recovered},
      {"aborted-overdue", c.sdo_guard.aborted_overdue},
      {"withdrawn-pending", c.sdo_guard.withdrawn_pending},
      {"withdrawn-answered-before", c.sdo_guard.withdrawn_answered_before},
      {"withdrawn-untracked", c.sdo_guard.withdrawn_untracked},
      {"late-answers-dropped", c.sdo_guard.late_responses_dropped},
      {"stale-answers-dropped", c.sdo_guard.stale_responses_dropped},
      {"stale-aborts-dropped", c.sdo_guard.stale_aborts_dropped},
  };
  s.nodes = snapshot.nodes;
  return s;
}

std::string surface_stats_line(const SurfaceStatsSnapshot& snapshot) {
  const SurfaceCounters& c = snapshot.counters;
  std::string s = fmt::format(
      "surface {}: {}/{} gateway(s) up, bus->backbone {} frames, backbone->bus {}, conflated {}, "
      "process-dropped {}, reliable-refused {}, reliable sent {} resent {}, dead-links {}, "
      "refusals {}/{}, sdo-aborted-link-down {} (withdrawn {}: pending {} answered-before {} "
      "untracked {}, answers recovered {}, overdue aborted {}, late answers dropped {}, "
      "stale answers dropped {}, stale aborts dropped {}), "
      "reliable dropped too-old {} gateway-restart {} (sdo aborted {}) expired-unacked {}, "
      "stale-links {}, "
      "echoes-dropped {}, "
      "bus-refused {}, dropped-no-gateway {}, unclaimed {}, "
      "malformed {}, unknown-module {}, node-events {}; "
      "pdop packets {} ({} bytes) discarded {} malformed {} probable-repeats {} bus-refused {}, "
      "rpdop forwarded {} complete {} failed {}; "
      "from-bus {} frames-received {} process-lost-on-line {} batches {} queued-total {}; {}; "
      "{}; bus-waited {} (peak {}, backbone-pauses {})",
      snapshot.name, snapshot.gateways_up, snapshot.gateways_configured, c.outbox.frames_sent,
      c.to_bus, c.outbox.conflated, c.outbox.process_dropped, c.outbox.reliable_refused,
      c.session.reliable_sent, c.session.reliable_resent, c.session.dead_links,
      c.session.refusals_sent, c.session.refusals_received, c.sdo_guard.aborted(),
      c.outbox.sdo_requests_withdrawn + c.sdo_requests_withdrawn_unacked,
      c.sdo_guard.withdrawn_pending, c.sdo_guard.withdrawn_answered_before,
      c.sdo_guard.withdrawn_untracked, c.sdo_guard.answers_recovered, c.sdo_guard.aborted_overdue,
      c.sdo_guard.late_responses_dropped, c.sdo_guard.stale_responses_dropped,
      c.sdo_guard.stale_aborts_dropped, c.reliable_dropped_too_old,
      c.reliable_dropped_gateway_restart, c.sdo_guard.aborted_discarded, c.reliable_expired_unacked,
      c.session.stale_links_closed, c.echoes_dropped, c.bus_refused, c.dropped_no_gateway,
      c.dropped_unclaimed, c.malformed_payloads + c.session.malformed, c.unknown_module,
      c.node_events, c.pdop.packets, c.pdop.packet_bytes, c.pdop.discards, c.pdop.malformed,
      c.pdop.probable_repeats, c.pdop_bus_refused, c.pdop.rpdop_forwarded, c.pdop.rpdop_complete,
      c.pdop.rpdop_failed, c.from_bus, c.frames_received, c.process_lost_on_line,
      c.outbox.batches_sent, c.outbox.queued, session_counters_text(c.session),
      bus_counters_text(snapshot.bus.interface, snapshot.bus.counters), c.bus_waited,
      c.bus_waiting_peak, c.backbone_pauses);
  for (std::size_t r = 0; r < BusWriteQueue::kDropReasons; ++r) {
    if (c.bus_drops[r] != 0) {
      s += fmt::format(" dropped-{} {}", to_string(static_cast<BusWriteQueue::Drop>(r)),
                       c.bus_drops[r]);
    }
  }
  s += fmt::format(", refused-strangers {}", c.refused_strangers);
  for (const auto& [gateway, drops] : c.not_its_own_by_gateway) {
    s += fmt::format(", not-its-own from '{}':", gateway);
    for (std::size_t r = 0; r < kNotItsOwnReasons; ++r) {
      if (drops[r] != 0) s += fmt::format(" {} {}", to_string(static_cast<NotItsOwn>(r)), drops[r]);
    }
  }
  s += "; " + lanes_summary(c.outbox);
  if (c.framing.frames + c.framing.discarded_bytes != 0) {
    s += "; " + framing_counters_text(c.framing);
  }
  return s;
}

}  // namespace canbridge::bridge
