// Frames waiting for one backbone peer: queued in CAN arbitration order (bounded, process data
// conflated per COB-ID), and packed into FrameBatch payloads when the session has room.
#pragma once

#include <cstdint>
#include <string>

#include "backbone/priority_scheduler.hpp"
#include "backbone/session.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

struct OutboxCounters {
  std::uint64_t queued = 0;
  std::uint64_t conflated = 0;         // process frames replaced by a newer value
  std::uint64_t process_dropped = 0;   // process frames dropped: queue full, no conflation
  std::uint64_t reliable_refused = 0;  // reliable frames refused: queue full (a failure)
  std::uint64_t frames_sent = 0;
  std::uint64_t batches_sent = 0;
};

class FrameOutbox {
 public:
  struct Options {
    std::size_t max_reliable_frames = 1u << 16;
    std::size_t max_process_frames = 1u << 14;
    // Upper bound of one FrameBatch payload: smaller batches lose less to one corrupted serial
    // frame; larger ones amortise the envelope.
    std::size_t max_batch_bytes = 4096;
  };

  explicit FrameOutbox(Options options);

  // Queues one frame of `module_id`; `conflate` allows replacing a queued process frame of the
  // same COB-ID. False when the frame was refused or dropped (counted).
  bool push(std::uint32_t module_id, const can::Frame& frame, bool conflate);

  // Moves queued frames into the session's write, lowest arbitration priority first, as
  // FrameBatch payloads: a run of frames of one module and one class per payload.
  void produce(backbone::PayloadSink& sink);

  bool empty() const { return queue_.empty(); }
  std::size_t size() const { return queue_.size(); }
  OutboxCounters counters() const;

 private:
  struct Entry {
    std::uint32_t module_id;
    can::Frame frame;
  };

  Options options_;
  backbone::PriorityScheduler<Entry> queue_;
  FrameBatchBuilder builder_;
  v1::Payload payload_;
  std::string serialized_;
  OutboxCounters counters_;
};

}  // namespace canbridge::bridge
