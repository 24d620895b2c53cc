// Converts runs of CAN frames to and from the backbone's column-wise FrameBatch message.
#pragma once

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

// Appends frames into a FrameBatch in place, so a batch under construction costs no allocation
// per frame once its fields have grown (protobuf keeps capacity across Clear()).
//
// A standard data frame goes into `head` alone (plus its payload); extended and remote frames are
// escaped to `escaped_can_id`. The wire has no bit for FrameFlags::error, so an error frame is
// sent as the data frame it would otherwise be; callers that must not forward error frames filter
// them before append(). Out-of-range frames are clamped the way can::Frame::make() would build
// them (id masked to 11 or 29 bits, len to kMaxPayload), so one bad frame never makes the
// receiver drop the whole batch.
class FrameBatchBuilder {
 public:
  explicit FrameBatchBuilder(bool carry_timestamps = false) : timestamps_(carry_timestamps) {}

  // Empties `batch` (keeping its capacity) and begins a batch for `module_id`.
  void start(v1::FrameBatch& batch, std::uint32_t module_id);
  void append(v1::FrameBatch& batch, const can::Frame& frame);

 private:
  bool timestamps_;
  std::int64_t last_us_ = 0;
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
