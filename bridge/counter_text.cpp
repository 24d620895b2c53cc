#include "bridge/counter_text.hpp"

#include <fmt/format.h>

namespace canbridge::bridge {

std::string bus_counters_text(const std::string& name, const can::BusCounters& c) {
  // "NAME rx N tx N kernel-drops N" first: scripts (bench/) read them in this order.
  return fmt::format(
      "{} rx {} tx {} kernel-drops {} rx-queue-drops {} tx-queue-refused {} tx-errors {} "
      "tx-retries {} error-frames {} reopens {} (while lost: tx-refused {} rx-dropped {}) {}",
      name, c.rx_frames, c.tx_frames, c.rx_dropped_kernel, c.rx_dropped_queue, c.tx_dropped_queue,
      c.tx_dropped_error, c.tx_retries, c.error_frames, c.reopens, c.tx_dropped_interface_lost,
      c.rx_dropped_interface_lost, can::to_string(c.state));
}

std::string session_counters_text(const backbone::SessionCounters& c) {
  return fmt::format(
      "session links {} protocol-errors {} before-hello {} keepalives {} resend-requests {} "
      "peer-restarts {} reliable delivered {} duplicates {} tombstones {}, unreliable sent {} "
      "delivered {} "
      "lost-on-line {}, auth ok {} refused key/proof/malformed/unauthenticated {}/{}/{}/{} "
      "restarts {} rejected truncated/bad-tag/replay {}/{}/{}",
      c.links, c.protocol_errors, c.before_hello, c.keepalives_sent, c.resend_requests,
      c.peer_restarts, c.reliable_delivered, c.reliable_duplicates, c.tombstones_received,
      c.unreliable_sent, c.unreliable_delivered, c.unreliable_lost, c.auth_established,
      c.auth_failed_unknown_key, c.auth_failed_bad_proof, c.auth_failed_malformed,
      c.auth_failed_unauthenticated, c.auth_restarts, c.rejected_truncated, c.rejected_bad_tag,
      c.rejected_replay);
}

std::string framing_counters_text(const backbone::DeframerCounters& c) {
  return fmt::format(
      "framing: frames {} crc-errors {} discarded-bytes {} cobs-errors {} oversize {} runts {}",
      c.frames, c.crc_errors, c.discarded_bytes, c.cobs_errors, c.oversize, c.runts);
}

}  // namespace canbridge::bridge
