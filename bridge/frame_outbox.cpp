#include "bridge/frame_outbox.hpp"

#include <algorithm>

#include "bridge/delivery_class.hpp"

namespace canbridge::bridge {

namespace {
// Upper bound of one frame's share of a FrameBatch: head (2), payload (8), an escaped id (5).
constexpr std::size_t kMaxFrameBytes = 15;
// Envelope, payload and batch headers around the frames: tags, lengths, module id, seq, ack.
constexpr std::size_t kBatchOverhead = 40;

std::size_t frame_bytes(const can::Frame& f) {
  const bool escaped = f.is_extended() || f.is_remote();
  return 2 + (f.is_remote() ? 0 : f.len) + (escaped ? 5 : 0);
}
}  // namespace

namespace {
bool is_sdo_request(const can::Frame& f) {
  return !f.is_extended() && f.id > 0x600 && f.id <= 0x67F;
}
}  // namespace

std::size_t withdraw_sdo_requests(std::string& payload) {
  v1::Payload parsed;
  std::vector<can::Frame> frames;
  if (!parsed.ParseFromString(payload) || !parsed.has_frames() ||
      decode_frame_batch(parsed.frames(), frames) != BatchError::none) {
    return 0;
  }
  const auto kept = std::remove_if(frames.begin(), frames.end(), is_sdo_request);
  const auto removed = static_cast<std::size_t>(frames.end() - kept);
  if (removed == 0) return 0;
  frames.erase(kept, frames.end());
  const bool timestamps = parsed.frames().timestamp_delta_us_size() != 0;
  const std::uint32_t module_id = parsed.frames().module_id();
  FrameBatchBuilder builder(timestamps);
  v1::FrameBatch& batch = *parsed.mutable_frames();
  builder.start(batch, module_id);
  for (const can::Frame& f : frames) builder.append(batch, f);
  payload.clear();
  parsed.AppendToString(&payload);
  return removed;
}

FrameOutbox::FrameOutbox(Options options)
    : options_(options), queue_({options.max_reliable_frames, options.max_process_frames}) {}

bool FrameOutbox::push(std::uint32_t module_id, const can::Frame& frame, bool conflate,
                       bool packet_fragment) {
  using Push = backbone::PriorityScheduler<Entry>::Push;
  packet_fragment = packet_fragment && !frame.is_extended() && !frame.is_remote();
  can::Frame first_fragment_id;
  if (packet_fragment) {
    first_fragment_id.id = frame.id & ~std::uint32_t{0x60};
    conflate = false;
  }
  const std::uint32_t priority = arbitration_priority(packet_fragment ? first_fragment_id : frame);
  const Push result = is_process_data(frame)
                          ? queue_.push_process(priority, conflation_key(module_id, frame),
                                                conflate || is_heartbeat_state(frame),
                                                Entry{module_id, frame, next_ordinal_})
                          : queue_.push_reliable(priority, Entry{module_id, frame, next_ordinal_});
  ++next_ordinal_;
  return result != Push::refused;
}

bool FrameOutbox::withdrawn(const Entry& entry) const {
  const can::Frame& f = entry.frame;
  return entry.ordinal < withdraw_before_ && is_sdo_request(f);
}

void FrameOutbox::produce(backbone::PayloadSink& sink) {
  while (sink.room() > kBatchOverhead + kMaxFrameBytes) {
    const auto front = queue_.front();
    if (!front) return;
    if (withdrawn(*front->item)) {
      queue_.pop();
      ++counters_.sdo_requests_withdrawn;
      continue;
    }
    const std::uint32_t module_id = front->item->module_id;
    const bool reliable = front->reliable;
    std::size_t budget = std::min(sink.room(), options_.max_batch_bytes) - kBatchOverhead;
    if (reliable) {
      // A smaller batch when the resend buffer has less room than a full one; nothing at all
      // (reliable payloads wait here, in order) when it cannot take even one frame.
      while (!sink.reliable_room(budget + kBatchOverhead)) {
        if (budget <= kMaxFrameBytes) return;
        budget = std::max(kMaxFrameBytes, budget / 2);
      }
    }
    v1::FrameBatch& batch = *payload_.mutable_frames();
    builder_.start(batch, module_id);
    std::size_t used = 0;
    std::size_t frames = 0;
    for (auto next = queue_.front(); next; next = queue_.front()) {
      if (withdrawn(*next->item)) {
        queue_.pop();
        ++counters_.sdo_requests_withdrawn;
        continue;
      }
      if (next->reliable != reliable || next->item->module_id != module_id) break;
      const std::size_t bytes = frame_bytes(next->item->frame);
      if (used + bytes > budget) break;
      builder_.append(batch, queue_.pop()->item.frame);
      used += bytes;
      ++frames;
    }
    if (frames == 0) return;  // cannot happen with budget >= kMaxFrameBytes; never loop on it
    if (!reliable) batch.set_process_frames_sent(process_frames_sent_ += frames);
    serialized_.clear();
    payload_.AppendToString(&serialized_);
    if (reliable) {
      sink.send_reliable(serialized_);
    } else {
      sink.send_unreliable(
          {reinterpret_cast<const std::uint8_t*>(serialized_.data()), serialized_.size()});
    }
    counters_.frames_sent += frames;
    ++counters_.batches_sent;
  }
}

OutboxCounters FrameOutbox::counters() const {
  const auto& q = queue_.counters();
  OutboxCounters c = counters_;
  c.queued = q.reliable_queued + q.process_queued;
  c.conflated = q.conflated;
  c.process_dropped = q.process_dropped;
  c.reliable_refused = q.reliable_refused;
  return c;
}

}  // namespace canbridge::bridge
