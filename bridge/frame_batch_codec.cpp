#include "bridge/frame_batch_codec.hpp"

#include <chrono>

namespace canbridge::bridge {

namespace {
// SocketCAN's can_id flag bits, used on the wire so a batch reads like struct can_frame.
constexpr std::uint32_t kEffFlag = 0x80000000u;
constexpr std::uint32_t kRtrFlag = 0x40000000u;
constexpr std::uint32_t kIdMask = 0x1FFFFFFFu;
}  // namespace

void FrameBatchBuilder::start(v1::FrameBatch& batch, std::uint32_t module_id) {
  batch.Clear();
  batch.set_module_id(module_id);
  last_us_ = 0;
}

void FrameBatchBuilder::append(v1::FrameBatch& batch, const can::Frame& frame) {
  std::uint32_t can_id = frame.id & kIdMask;
  if (frame.is_extended()) can_id |= kEffFlag;
  if (frame.is_remote()) can_id |= kRtrFlag;
  batch.add_can_id(can_id);
  batch.mutable_length()->push_back(static_cast<char>(frame.len));
  if (!frame.is_remote()) {
    batch.mutable_data()->append(reinterpret_cast<const char*>(frame.data.data()), frame.len);
  }
  if (timestamps_) {
    const std::int64_t us =
        std::chrono::duration_cast<std::chrono::microseconds>(frame.timestamp).count();
    batch.add_timestamp_delta_us(us - last_us_);
    last_us_ = us;
  }
}

std::string_view to_string(BatchError error) {
  switch (error) {
    case BatchError::none:
      return "none";
    case BatchError::column_mismatch:
      return "column-mismatch";
    case BatchError::bad_length:
      return "bad-length";
    case BatchError::bad_id:
      return "bad-id";
    case BatchError::data_size_mismatch:
      return "data-size-mismatch";
  }
  return "unknown";
}

BatchError decode_frame_batch(const v1::FrameBatch& batch, std::vector<can::Frame>& out) {
  const int n = batch.can_id_size();
  const std::string& lengths = batch.length();
  const std::string& data = batch.data();
  if (static_cast<std::size_t>(n) != lengths.size() ||
      (batch.timestamp_delta_us_size() != 0 && batch.timestamp_delta_us_size() != n)) {
    return BatchError::column_mismatch;
  }
  const std::size_t first = out.size();
  std::size_t offset = 0;
  std::int64_t us = 0;
  for (int i = 0; i < n; ++i) {
    const std::uint32_t can_id = batch.can_id(i);
    const auto len = static_cast<std::uint8_t>(lengths[static_cast<std::size_t>(i)]);
    if (len > can::kMaxPayload) {
      out.resize(first);
      return BatchError::bad_length;
    }
    can::Frame f;
    f.flags = static_cast<std::uint8_t>(((can_id & kEffFlag) ? can::FrameFlags::extended : 0) |
                                        ((can_id & kRtrFlag) ? can::FrameFlags::remote : 0));
    f.id = can_id & kIdMask;
    if (!f.is_extended() && f.id > can::kMaxStandardId) {
      out.resize(first);
      return BatchError::bad_id;
    }
    f.len = len;
    if (!f.is_remote()) {
      if (offset + len > data.size()) {
        out.resize(first);
        return BatchError::data_size_mismatch;
      }
      std::copy_n(data.data() + offset, len, reinterpret_cast<char*>(f.data.data()));
      offset += len;
    }
    if (batch.timestamp_delta_us_size() != 0) {
      us += batch.timestamp_delta_us(i);
      f.timestamp = std::chrono::microseconds(us);
    }
    out.push_back(f);
  }
  if (offset != data.size()) {
    out.resize(first);
    return BatchError::data_size_mismatch;
  }
  return BatchError::none;
}

}  // namespace canbridge::bridge
