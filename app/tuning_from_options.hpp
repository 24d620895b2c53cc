// Turns a role's validated session options into the backbone tuning its sessions and outboxes
// take, so that bridge/ never sees config/.
#pragma once

#include <algorithm>
#include <cstddef>

#include "bridge/backbone_tuning.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

// The write bound when the config leaves it to the link: TCP takes large writes (fewer system
// calls); a serial line takes about 50 ms of line time per write, because a frame queued during a
// write waits for it to end (576 bytes at 115200 bit/s, 5000 at 1 Mbit/s).
inline std::size_t derived_max_write_bytes(std::size_t slowest_line_bytes_per_second) {
  constexpr std::size_t kTcpWriteBytes = 16 * 1024;
  if (slowest_line_bytes_per_second == 0) return kTcpWriteBytes;
  return std::clamp<std::size_t>(slowest_line_bytes_per_second / 20, 256, kTcpWriteBytes);
}

// `slowest_line_bytes_per_second`: the slowest serial line of the role (baud / 10), 0 for TCP.
inline BackboneTuning make_tuning(const config::SessionTuning& config,
                                  std::size_t slowest_line_bytes_per_second = 0) {
  config::SessionTuning t = config;
  if (t.max_write_bytes == 0)
    t.max_write_bytes = derived_max_write_bytes(slowest_line_bytes_per_second);
  BackboneTuning out;
  out.session.keepalive_interval = t.keepalive;
  out.session.dead_after = t.dead_after;
  out.session.retransmit_timeout = t.retransmit;
  out.session.reliable_max_age = t.reliable_max_age;
  out.outbox.reliable_max_age = t.reliable_max_age;
  out.session.resend_buffer_messages = t.resend_buffer_messages;
  out.session.resend_buffer_bytes = t.resend_buffer_bytes;
  out.session.max_write_bytes = t.max_write_bytes;
  out.outbox.max_reliable_frames = t.queue_reliable_frames;
  out.outbox.max_process_frames = t.queue_process_frames;
  out.outbox.conflate_after = t.conflate_after;
  // One batch never exceeds a write, nor a quarter of the resend buffer (so it always fits).
  out.outbox.max_batch_bytes = std::max<std::size_t>(
      64, std::min({t.max_write_bytes, t.resend_buffer_bytes / 4, std::size_t{4096}}));
  return out;
}

}  // namespace canbridge::bridge
