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
  std::uint64_t sdo_requests_withdrawn = 0;  // dropped by withdraw_queued_sdo_requests()
};

// SDO requests (0x601-0x67F) removed from one serialized Payload this outbox produced, for the
// unacknowledged ones a session would resend: the other frames stay, in order. Returns how many
// were removed (0 leaves `payload` untouched; an unparsable payload is left alone).
std::size_t withdraw_sdo_requests(std::string& payload);

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
  // `packet_fragment`: a PDO Packet fragment crossing as a frame (docs/pdop.md section 8,
  // `reassemble: false`). Its four t/c variants are different COB-IDs, which arbitration order
  // would send last fragment first; it is ordered as its packet's first fragment (bits 6-5
  // clear), so a packet's fragments leave in bus order. Never conflated (fragment k and k + 2
  // share a COB-ID).
  bool push(std::uint32_t module_id, const can::Frame& frame, bool conflate,
            bool packet_fragment = false);

  // Moves queued frames into the session's write, lowest arbitration priority first, as
  // FrameBatch payloads: a run of frames of one module and one class per payload.
  void produce(backbone::PayloadSink& sink);

  // SDO requests (0x601-0x67F) queued now are never sent: the surface has answered them with an
  // abort because the peer's link went down, and a node must not execute later a request its
  // master was told failed. Frames queued afterwards are not affected.
  void withdraw_queued_sdo_requests() { withdraw_before_ = next_ordinal_; }

  bool empty() const { return queue_.empty(); }
  std::size_t size() const { return queue_.size(); }
  OutboxCounters counters() const;

 private:
  struct Entry {
    std::uint32_t module_id;
    can::Frame frame;
    std::uint64_t ordinal;  // push order, for withdraw_queued_sdo_requests()
  };
  bool withdrawn(const Entry& entry) const;

  Options options_;
  backbone::PriorityScheduler<Entry> queue_;
  FrameBatchBuilder builder_;
  v1::Payload payload_;
  std::string serialized_;
  OutboxCounters counters_;
  std::uint64_t next_ordinal_ = 0;
  std::uint64_t process_frames_sent_ = 0;  // in unreliable batches: FrameBatch.process_frames_sent
  std::uint64_t withdraw_before_ = 0;
};

}  // namespace canbridge::bridge
