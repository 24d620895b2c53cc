#include "bridge/frame_batch_codec.hpp"

#include <gtest/gtest.h>

#include <random>

namespace canbridge::bridge {
namespace {

using can::Frame;

std::vector<Frame> random_frames(std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<Frame> frames;
  for (std::size_t i = 0; i < n; ++i) {
    Frame f;
    const unsigned kind = rng() % 4;
    f.flags = kind == 1 ? can::FrameFlags::extended : kind == 2 ? can::FrameFlags::remote : 0;
    f.id = rng() & (f.is_extended() ? can::kMaxExtendedId : can::kMaxStandardId);
    f.len = static_cast<std::uint8_t>(rng() % 9);
    for (auto& b : f.data) b = static_cast<std::uint8_t>(rng());
    f.timestamp =
        std::chrono::microseconds(1'700'000'000'000'000LL + static_cast<long long>(i) * 37);
    frames.push_back(f);
  }
  return frames;
}

TEST(FrameBatchCodec, RoundTripsEveryKindOfFrameWithTimestamps) {
  const auto frames = random_frames(1000, 7);
  v1::FrameBatch batch;
  FrameBatchBuilder builder(true);
  builder.start(batch, 3);
  for (const auto& f : frames) builder.append(batch, f);
  v1::FrameBatch parsed;
  ASSERT_TRUE(parsed.ParseFromString(batch.SerializeAsString()));
  std::vector<Frame> out;
  ASSERT_EQ(decode_frame_batch(parsed, out), BatchError::none);
  ASSERT_EQ(out.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(out[i], frames[i]) << i;
    EXPECT_EQ(out[i].timestamp, frames[i].timestamp) << i;
  }
  EXPECT_EQ(parsed.module_id(), 3u);
}

TEST(FrameBatchCodec, FullBatchOfStandardFramesCostsAtMostElevenBytesPerFrame) {
  v1::FrameBatch batch;
  FrameBatchBuilder builder;
  builder.start(batch, 1);
  for (int i = 0; i < 500; ++i)
    builder.append(batch, Frame::standard(0x181 + (i % 100), {1, 2, 3, 4, 5, 6, 7, 8}));
  const double per_frame = static_cast<double>(batch.ByteSizeLong()) / 500.0;
  EXPECT_LE(per_frame, 11.1);
}

TEST(FrameBatchCodec, RefusesInconsistentBatchesWithoutPartialOutput) {
  std::vector<Frame> out(1);
  v1::FrameBatch b;
  b.add_can_id(0x123);
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::column_mismatch);
  b.set_length(std::string(1, '\x09'));
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::bad_length);
  b.set_length(std::string(1, '\x02'));
  b.set_data("x");
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::data_size_mismatch);
  b.set_data("xyz");
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::data_size_mismatch);
  b.set_data("xy");
  b.set_can_id(0, 0x800);  // standard frame with an 12-bit id
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::bad_id);
  EXPECT_EQ(out.size(), 1u);
  b.set_can_id(0, 0x7FF);
  EXPECT_EQ(decode_frame_batch(b, out), BatchError::none);
  EXPECT_EQ(out.size(), 2u);
}

}  // namespace
}  // namespace canbridge::bridge
