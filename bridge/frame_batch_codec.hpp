// Converts runs of CAN frames to and from the backbone's column-wise FrameBatch message.
#pragma once

#include <cstdint>
#include <string_view>
#include <vector>

#include "can/frame.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

// FrameBatch.module_id of surface -> gateway traffic that the gateway routes by COB-ID.
inline constexpr std::uint32_t kAnyModule = 0xFFFFFFFFu;

// Appends frames into a FrameBatch in place, so a batch under construction costs no allocation
// per frame once its fields have grown (protobuf keeps capacity across Clear()).
class FrameBatchBuilder {
 public:
  explicit FrameBatchBuilder(bool carry_timestamps = false) : timestamps_(carry_timestamps) {}

  void start(v1::FrameBatch& batch, std::uint32_t module_id);
  void append(v1::FrameBatch& batch, const can::Frame& frame);

 private:
  bool timestamps_;
  std::int64_t last_us_ = 0;
};

// Why a received FrameBatch was refused (the whole batch is dropped and counted).
enum class BatchError : std::uint8_t {
  none,
  column_mismatch,
  bad_length,
  bad_id,
  data_size_mismatch
};
std::string_view to_string(BatchError error);

// Decodes every frame of `batch` into `out` (appending). On error `out` is left as it was.
BatchError decode_frame_batch(const v1::FrameBatch& batch, std::vector<can::Frame>& out);

}  // namespace canbridge::bridge
