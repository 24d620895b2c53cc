// Turns a role's validated session options into the backbone tuning its sessions and outboxes
// take, so that bridge/ never sees config/.
#pragma once

#include <algorithm>
#include <cstddef>

#include "bridge/backbone_tuning.hpp"
#include "config/options.hpp"

namespace canbridge::bridge {

inline BackboneTuning make_tuning(const config::SessionTuning& t) {
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
