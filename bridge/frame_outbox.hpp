// Frames waiting for one backbone peer, in the lanes of their delivery class (bounded; each
// sender's frames in its order, the senders in CAN arbitration order), packed into FrameBatch
// payloads when the session has room.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <string>

#include "backbone/priority_scheduler.hpp"
#include "backbone/session.hpp"
#include "bridge/delivery_class.hpp"
#include "bridge/delivery_lanes.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

// One frame lane's counts (kLanes gives each lane's overflow rule).
struct LaneCounters {
  std::uint64_t queued = 0;          // new entries (conflations not included)
  std::uint64_t conflated = 0;       // a newer value replaced the queued one
  std::uint64_t dropped_oldest = 0;  // the lane was full: its oldest frame made room
  std::uint64_t refused = 0;         // the lane was full: the new frame was refused
};

struct OutboxCounters {
  // Totals over the lanes, under the names of the stats lines.
  std::uint64_t queued = 0;
  std::uint64_t conflated = 0;         // latest values and process frames replaced by a newer one
  std::uint64_t process_dropped = 0;   // unreliable frames lost to a full lane (dropped/refused)
  std::uint64_t reliable_refused = 0;  // reliable frames refused: lane full (a failure)
  std::uint64_t frames_sent = 0;
  std::uint64_t batches_sent = 0;
  std::uint64_t sdo_requests_withdrawn = 0;       // dropped by withdraw_queued_sdo_requests()
  std::uint64_t reliable_too_old = 0;             // reliable frames older than reliable_max_age
  std::uint64_t discarded_peer_restart = 0;       // frames queued for a peer process that is gone
  std::array<LaneCounters, kFrameLanes> lanes{};  // indexed by DeliveryClass

  OutboxCounters& operator+=(const OutboxCounters& other);
};

// "lane reliable queued 3 conflated 0 dropped-oldest 0 refused 0, lane latest-value ...": every
// frame lane's counts, for a stats line.
std::string lanes_summary(const OutboxCounters& counters);

// True for an SDO request on a default server channel (0x601-0x67F).
bool is_sdo_request(const can::Frame& frame);
// True for an SDO request to `node` (any node if it is 0).
bool is_sdo_request_to(const can::Frame& frame, std::uint8_t node);

// Sees each SDO request withdrawn, so that its sender can account for its answer.
using WithdrawnObserver = std::function<void(const can::Frame& request)>;

// SDO requests (0x601-0x67F; only those to `node`, if it is not 0) removed from one serialized
// Payload this outbox produced, for the unacknowledged ones a session would resend: the other
// frames stay, in order. Returns how many were removed (0 leaves `payload` untouched; an
// unparsable payload is left alone); `withdrawn` (if set) sees each.
std::size_t withdraw_sdo_requests(std::string& payload,
                                  const WithdrawnObserver& withdrawn = nullptr,
                                  std::uint8_t node = 0);

class FrameOutbox {
 public:
  struct Options : LaneBounds {
    // Upper bound of one FrameBatch payload: smaller batches lose less to one corrupted serial
    // frame; larger ones amortise the envelope.
    std::size_t max_batch_bytes = 4096;
    // A reliable frame queued longer than this is never sent (backbone::SessionOptions has the
    // same bound for what was sent and not yet acknowledged). Zero: no limit.
    std::chrono::milliseconds reliable_max_age{0};
    // Process data of a module that conflates (`conflate_pdos`) is conflated only while the link
    // is behind that COB-ID: when its oldest queued frame has waited longer than this. Until
    // then every frame is kept, in order, so a burst the link can carry crosses whole (and in
    // large batches). Zero: always conflate.
    std::chrono::milliseconds conflate_after{200};
  };
  using Clock = std::chrono::steady_clock;
  enum class Discard { too_old, peer_restart };
  // Sees every reliable frame the outbox gives up on (so its sender can answer the requests
  // among them).
  using DiscardObserver =
      std::function<void(std::uint32_t module_id, const can::Frame& frame, Discard why)>;

  explicit FrameOutbox(Options options);

  // Queues one frame of `module_id` in the lane of its delivery class (classify(frame,
  // options)). False when the frame was refused (counted): a reliable frame that will not be sent,
  // or a fragment. A frame that displaced an older value is queued (the drop is counted).
  // `now`: when the frame was read off its bus, for reliable_max_age and conflate_after; one
  // reading serves a whole batch read off the bus (a clock read can be a system call).
  bool push(std::uint32_t module_id, const can::Frame& frame, const DeliveryOptions& options,
            Clock::time_point now);

  // Moves queued frames into the session's write, lowest arbitration priority first, as
  // FrameBatch payloads: a run of frames of one module and one reliability per payload.
  void produce(backbone::PayloadSink& sink);

  // SDO requests (0x601-0x67F; only those to `node`, if it is not 0) queued now are never sent:
  // the surface has answered them with an abort (the peer's link went down, or the answer is
  // overdue), and a node must not execute later a request its master was told failed. Frames
  // queued afterwards are not affected. `withdrawn` (if set) sees each.
  void withdraw_queued_sdo_requests(const WithdrawnObserver& withdrawn = nullptr,
                                    std::uint8_t node = 0);

  // Whether the batches may use FrameBatch.head_runs: on when the peer's hello says it decodes
  // them (protocol minor >= kHeadRunsMinor); set on every link, before it carries anything.
  void set_head_runs(bool on) { builder_.set_head_runs(on); }

  // The peer this outbox feeds is a new process: everything queued was meant for the old one.
  void discard_queued();
  void on_discard(DiscardObserver observer) { on_discard_ = std::move(observer); }

  bool empty() const { return queue_.empty(); }
  std::size_t size() const { return queue_.size(); }
  std::size_t lane_size(DeliveryClass delivery) const {
    return queue_.lane_size(static_cast<std::size_t>(delivery));
  }
  OutboxCounters counters() const;

 private:
  struct Entry {
    std::uint32_t module_id;
    can::Frame frame;
    Clock::time_point born;  // read off its bus
  };
  // Pops the front entry if it is a reliable frame older than reliable_max_age; true if it did.
  bool drop_front_if_too_old(Clock::time_point now);

  Options options_;
  backbone::PriorityScheduler<Entry> queue_;
  FrameBatchBuilder builder_;
  v1::Payload payload_;
  std::string serialized_;
  OutboxCounters counters_;
  DiscardObserver on_discard_;
  std::uint64_t process_frames_sent_ = 0;  // in unreliable batches: FrameBatch.process_frames_sent
};

}  // namespace canbridge::bridge
