// Converts runs of CAN frames to and from the backbone's column-wise FrameBatch message.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "can/frame.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

// FrameBatch.module_id of surface -> gateway traffic that the gateway routes by COB-ID.
inline constexpr std::uint32_t kAnyModule = 0xFFFFFFFFu;

// Hello.protocol_minor from which a peer decodes FrameBatch.head_runs: only such a peer is sent
// batches built with head runs (FrameOutbox::set_head_runs); older ones get the plain form.
inline constexpr std::uint32_t kHeadRunsMinor = 6;
// Most frames one FrameBatch may decode to: runs make frames cheap on the wire (a zero-length
// frame costs nothing in a run), so the count is bounded rather than the bytes.
inline constexpr std::size_t kMaxBatchFrames = 65536;

// Appends frames into a FrameBatch in place, so a batch under construction costs no allocation
// per frame once its fields have grown (protobuf keeps capacity across Clear()).
//
// A standard data frame goes into `head` alone (plus its payload); extended and remote frames are
// escaped to `escaped_can_id`. The wire has no bit for FrameFlags::error, so an error frame is
// sent as the data frame it would otherwise be; callers that must not forward error frames filter
// them before append(). Out-of-range frames are clamped the way can::Frame::make() would build
// them (id masked to 11 or 29 bits, len to kMaxPayload), so one bad frame never makes the
// receiver drop the whole batch.
//
// With head runs on (only toward a peer at protocol minor >= kHeadRunsMinor), a frame whose head
// and escaped id equal its predecessor's extends that head's run in `head_runs` instead of
// repeating them: a burst of one COB-ID costs its payload bytes alone. The caller bounds a batch
// (FrameOutbox's byte budget keeps it far below kMaxBatchFrames).
class FrameBatchBuilder {
 public:
  explicit FrameBatchBuilder(bool carry_timestamps = false, bool head_runs = false)
      : timestamps_(carry_timestamps), runs_(head_runs) {}

  // Empties `batch` (keeping its capacity) and begins a batch for `module_id`.
  void start(v1::FrameBatch& batch, std::uint32_t module_id);
  void append(v1::FrameBatch& batch, const can::Frame& frame);

  // About the bytes append(batch, frame) would add to the batch being built (an upper bound
  // within a byte or two), so a caller filling a byte budget fills it with what runs save.
  std::size_t cost(const can::Frame& frame) const;

  // Between batches: a batch must not hold runs when its receiver may be older.
  void set_head_runs(bool on) { runs_ = on; }
  bool head_runs() const { return runs_; }

 private:
  bool timestamps_;
  bool runs_;
  std::int64_t last_us_ = 0;
  // The latest head word appended (and its escaped can_id), to see a run continue.
  bool have_last_ = false;
  std::uint16_t last_word_ = 0;
  std::uint32_t last_can_id_ = 0;
  std::size_t words_ = 0;     // head words in the batch
  std::size_t run_base_ = 0;  // the word after the latest run's word: where the next gap counts
  bool last_in_run_ = false;  // the latest word already has a head_runs pair (the last one)
};

// Why a received FrameBatch was refused (the whole batch is dropped and counted).
enum class BatchError : std::uint8_t {
  none,
  column_mismatch,     // odd-length head, or timestamps present but not one per frame
  bad_length,          // head length bits above kMaxPayload
  bad_id,              // standard id above 0x7FF, unknown can_id flag, or id bits on an escape
  data_size_mismatch,  // data is not exactly the payloads of the data frames
  escape_mismatch,     // head escapes and escaped_can_id entries differ in number
  bad_timestamp,       // the running timestamp leaves what std::chrono::nanoseconds holds
  bad_run,             // head_runs not pairs, a gap of 0 or past the last word, repeats of 0
  too_many_frames,     // more than kMaxBatchFrames frames
};
std::string_view to_string(BatchError error);

// Decodes every frame of `batch` into `out` (appending). On error `out` is left as it was: the
// batch is validated completely before the first frame is appended.
BatchError decode_frame_batch(const v1::FrameBatch& batch, std::vector<can::Frame>& out);

// A received session payload (a serialized v1::Payload) decoded into frames: `payload` receives
// the parsed message (reused across calls, so parsing allocates only while it grows), `frames`
// the frames (cleared first). Returns nullopt when it holds a valid frame batch, else why not,
// for a counter and a warning.
std::optional<std::string> decode_frame_payload(std::span<const std::uint8_t> bytes,
                                                v1::Payload& payload,
                                                std::vector<can::Frame>& frames);

}  // namespace canbridge::bridge
