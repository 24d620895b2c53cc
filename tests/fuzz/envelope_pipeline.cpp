#include "tests/fuzz/envelope_pipeline.hpp"

#include <cstdio>
#include <cstdlib>
#include <vector>

#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "session.pb.h"

namespace canbridge::fuzz {

namespace {

void check_frame_batch(const v1::FrameBatch& batch) {
  // A frame already in the output: decode_frame_batch appends, and must leave it alone.
  const can::Frame sentinel = can::Frame::standard(0x123, {0xAA, 0x55});
  std::vector<can::Frame> frames{sentinel};
  const bridge::BatchError error = bridge::decode_frame_batch(batch, frames);
  require(!frames.empty() && frames.front() == sentinel, "decode touched frames it did not add");
  require(bridge::to_string(error) != "unknown", "BatchError without a name");
  if (error != bridge::BatchError::none) {
    require(frames.size() == 1, "a refused batch left frames behind");
    return;
  }

  const bool timed = batch.timestamp_delta_us_size() != 0;
  for (std::size_t i = 1; i < frames.size(); ++i) {
    const can::Frame& f = frames[i];
    require(f.len <= can::kMaxPayload, "decoded frame longer than a CAN frame");
    require(f.id <= (f.is_extended() ? can::kMaxExtendedId : can::kMaxStandardId),
            "decoded identifier out of range");
    require(!f.is_error(), "the wire carries no error frames");
    require(timed || f.timestamp.count() == 0, "timestamp without a timestamp column");
  }

  // Whatever form the batch had, the builder's canonical forms must decode to the same frames:
  // the plain one (for a peer before protocol 2.6) and the one with head runs.
  for (const bool runs : {false, true}) {
    bridge::FrameBatchBuilder builder(timed, runs);
    v1::FrameBatch again;
    builder.start(again, batch.module_id());
    for (std::size_t i = 1; i < frames.size(); ++i) builder.append(again, frames[i]);
    require(again.module_id() == batch.module_id(), "module id lost");
    require(runs || again.head_runs_size() == 0, "head runs in the plain form");
    std::vector<can::Frame> redecoded;
    require(bridge::decode_frame_batch(again, redecoded) == bridge::BatchError::none,
            "a re-encoded batch was refused");
    require(redecoded.size() + 1 == frames.size(), "re-encoding changed the frame count");
    for (std::size_t i = 0; i < redecoded.size(); ++i) {
      require(redecoded[i] == frames[i + 1], "re-encoding changed a frame");
      require(redecoded[i].timestamp == frames[i + 1].timestamp, "re-encoding changed a timestamp");
    }
  }
}

}  // namespace

void require(bool holds, const char* invariant) {
  if (holds) return;
  std::fprintf(stderr, "fuzz invariant violated: %s\n", invariant);
  std::abort();
}

void process_envelope(std::span<const std::uint8_t> message) {
  v1::Envelope envelope;
  if (!envelope.ParseFromArray(message.data(), static_cast<int>(message.size()))) return;
  if (envelope.body_case() != v1::Envelope::kPayload) return;
  v1::Payload payload;
  if (!payload.ParseFromString(envelope.payload())) return;
  if (payload.body_case() != v1::Payload::kFrames) return;
  check_frame_batch(payload.frames());
}

}  // namespace canbridge::fuzz
