#include "bridge/frame_outbox.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <vector>

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

bool is_sdo_request(const can::Frame& f) {
  return !f.is_extended() && f.id > 0x600 && f.id <= 0x67F;
}

bool is_sdo_request_to(const can::Frame& f, std::uint8_t node) {
  return is_sdo_request(f) && (node == 0 || f.id == 0x600u + node);
}

std::size_t withdraw_sdo_requests(std::string& payload, const WithdrawnObserver& withdrawn,
                                  std::uint8_t node) {
  v1::Payload parsed;
  std::vector<can::Frame> frames;
  if (!parsed.ParseFromString(payload) || !parsed.has_frames() ||
      decode_frame_batch(parsed.frames(), frames) != BatchError::none) {
    return 0;
  }
  const auto kept =
      std::stable_partition(frames.begin(), frames.end(),
                            [node](const can::Frame& f) { return !is_sdo_request_to(f, node); });
  const auto removed = static_cast<std::size_t>(frames.end() - kept);
  if (removed == 0) return 0;
  if (withdrawn) std::for_each(kept, frames.end(), withdrawn);
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

namespace {
// The scheduler's lanes, in kLanes order (the frame lanes only).
std::vector<backbone::SchedulerLane> scheduler_lanes(const LaneBounds& bounds) {
  std::vector<backbone::SchedulerLane> lanes;
  for (std::size_t i = 0; i < kFrameLanes; ++i) {
    lanes.push_back({bounds.*kLanes[i].bound, kLanes[i].overflow});
  }
  return lanes;
}

// The identifier of a PDO Packet's first fragment (bits 6-5, t and c, clear): its four t/c
// variants are different COB-IDs, which arbitration order would send last fragment first.
can::Frame first_fragment_of(const can::Frame& fragment) {
  can::Frame first = fragment;
  first.id &= ~std::uint32_t{0x60};
  return first;
}

// The FIFO a frame joins in its lane (FifoPer), unique per module.
std::uint64_t fifo_key(const Lane& lane, std::uint32_t module_id, const can::Frame& frame) {
  switch (lane.fifo) {
    case FifoPer::sender:
      return (std::uint64_t{module_id} << 32) | bus_sender(frame);
    case FifoPer::packet:
      return conflation_key(module_id, first_fragment_of(frame));
    case FifoPer::cob_id:
    case FifoPer::role:
      break;
  }
  return conflation_key(module_id, frame);
}

// Where the FIFO's head competes: its arbitration order, a fragment as its packet's first one.
std::uint32_t priority_of(const Lane& lane, const can::Frame& frame) {
  return arbitration_priority(lane.fifo == FifoPer::packet ? first_fragment_of(frame) : frame);
}
}  // namespace

FrameOutbox::FrameOutbox(Options options) : options_(options), queue_(scheduler_lanes(options)) {}

bool FrameOutbox::push(std::uint32_t module_id, const can::Frame& frame,
                       const DeliveryOptions& options, Clock::time_point now) {
  const DeliveryClass delivery = classify(frame, options);
  const Lane& lane = lane_of(delivery);
  const std::size_t lane_index = static_cast<std::size_t>(delivery);
  const std::uint64_t stream = fifo_key(lane, module_id, frame);
  const auto link_behind = [&] {
    if (options_.conflate_after.count() <= 0) return true;
    const Entry* head = queue_.stream_head(lane_index, stream);
    return head != nullptr && now - head->born > options_.conflate_after;
  };
  const bool replace =
      lane.conflation == Conflation::always ||
      (lane.conflation == Conflation::module_option && options.conflate_pdos && link_behind());
  const auto result = queue_.push(lane_index, stream, priority_of(lane, frame), replace,
                                  Entry{module_id, frame, now});
  return result != backbone::SchedulerPush::refused;
}

void FrameOutbox::withdraw_queued_sdo_requests(const WithdrawnObserver& withdrawn,
                                               std::uint8_t node) {
  counters_.sdo_requests_withdrawn += queue_.erase_if([&](const Entry& entry) {
    if (!is_sdo_request_to(entry.frame, node)) return false;
    if (withdrawn) withdrawn(entry.frame);
    return true;
  });
}

bool FrameOutbox::drop_front_if_too_old(Clock::time_point now) {
  const auto front = queue_.front();
  if (!front || !kLanes[front->lane].reliable || options_.reliable_max_age.count() <= 0 ||
      now - front->item->born <= options_.reliable_max_age) {
    return false;
  }
  const Entry old = queue_.pop()->item;
  ++counters_.reliable_too_old;
  if (on_discard_) on_discard_(old.module_id, old.frame, Discard::too_old);
  return true;
}

void FrameOutbox::discard_queued() {
  while (auto popped = queue_.pop()) {
    ++counters_.discarded_peer_restart;
    if (kLanes[popped->lane].reliable && on_discard_) {
      on_discard_(popped->item.module_id, popped->item.frame, Discard::peer_restart);
    }
  }
}

void FrameOutbox::produce(backbone::PayloadSink& sink) {
  const Clock::time_point now = sink.now();
  while (sink.room() > kBatchOverhead + kMaxFrameBytes) {
    if (drop_front_if_too_old(now)) continue;
    const auto front = queue_.front();
    if (!front) return;
    const std::uint32_t module_id = front->item->module_id;
    const bool reliable = kLanes[front->lane].reliable;
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
    Clock::time_point born = now;
    for (auto next = queue_.front(); next; next = queue_.front()) {
      if (drop_front_if_too_old(now)) continue;
      if (kLanes[next->lane].reliable != reliable || next->item->module_id != module_id) break;
      // With head runs a repeated head costs nothing: count what the batch really grows by.
      const std::size_t bytes =
          builder_.head_runs() ? builder_.cost(next->item->frame) : frame_bytes(next->item->frame);
      if (used + bytes > budget) break;
      born = std::min(born, next->item->born);
      builder_.append(batch, queue_.pop()->item.frame);
      used += bytes;
      ++frames;
    }
    if (frames == 0) return;  // cannot happen with budget >= kMaxFrameBytes; never loop on it
    if (!reliable) batch.set_process_frames_sent(process_frames_sent_ += frames);
    serialized_.clear();
    payload_.AppendToString(&serialized_);
    if (reliable) {
      sink.send_reliable_since(serialized_, born);
    } else {
      sink.send_unreliable(
          {reinterpret_cast<const std::uint8_t*>(serialized_.data()), serialized_.size()});
    }
    counters_.frames_sent += frames;
    ++counters_.batches_sent;
  }
}

OutboxCounters FrameOutbox::counters() const {
  OutboxCounters c = counters_;
  for (std::size_t i = 0; i < kFrameLanes; ++i) {
    const auto& q = queue_.counters(i);
    c.lanes[i] = {q.queued, q.conflated, q.dropped_oldest, q.refused};
    c.queued += q.queued;
    c.conflated += q.conflated;
    (kLanes[i].reliable ? c.reliable_refused : c.process_dropped) += q.refused;
    // A reliable lane never drops (Overflow::refuse); if one ever did, it would show here.
    (kLanes[i].reliable ? c.reliable_refused : c.process_dropped) += q.dropped_oldest;
  }
  return c;
}

OutboxCounters& OutboxCounters::operator+=(const OutboxCounters& other) {
  queued += other.queued;
  conflated += other.conflated;
  process_dropped += other.process_dropped;
  reliable_refused += other.reliable_refused;
  frames_sent += other.frames_sent;
  batches_sent += other.batches_sent;
  sdo_requests_withdrawn += other.sdo_requests_withdrawn;
  reliable_too_old += other.reliable_too_old;
  discarded_peer_restart += other.discarded_peer_restart;
  for (std::size_t i = 0; i < lanes.size(); ++i) {
    lanes[i].queued += other.lanes[i].queued;
    lanes[i].conflated += other.lanes[i].conflated;
    lanes[i].dropped_oldest += other.lanes[i].dropped_oldest;
    lanes[i].refused += other.lanes[i].refused;
  }
  return *this;
}

std::string lanes_summary(const OutboxCounters& counters) {
  std::string out;
  for (std::size_t i = 0; i < kFrameLanes; ++i) {
    const LaneCounters& l = counters.lanes[i];
    out += fmt::format("{}lane {} queued {} conflated {} dropped-oldest {} refused {}",
                       i == 0 ? "" : ", ", kLanes[i].name, l.queued, l.conflated, l.dropped_oldest,
                       l.refused);
  }
  return out;
}

}  // namespace canbridge::bridge
