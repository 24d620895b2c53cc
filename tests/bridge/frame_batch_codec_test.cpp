#include "bridge/frame_batch_codec.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <iostream>
#include <limits>
#include <random>
#include <set>
#include <span>
#include <string>
#include <vector>

#include "bridge/frame_outbox.hpp"

namespace canbridge::bridge {
namespace {

using can::Frame;
using can::FrameFlags;

// The head bytes of one frame, written out by hand so the tests pin the wire layout rather
// than re-deriving it from the codec.
std::string head(std::uint16_t word) {
  return {static_cast<char>(word & 0xFF), static_cast<char>(word >> 8)};
}

Frame frame(std::uint32_t id, std::uint8_t flags, std::uint8_t len) {
  Frame f;
  f.id = id;
  f.flags = flags;
  f.len = len;
  for (std::uint8_t i = 0; i < can::kMaxPayload; ++i) {
    f.data[i] = static_cast<std::uint8_t>(0xA0 + 0x11 * i + len);
  }
  return f;
}

v1::FrameBatch build(const std::vector<Frame>& frames, bool timestamps = false,
                     std::uint32_t module_id = 1, bool head_runs = false) {
  v1::FrameBatch batch;
  FrameBatchBuilder builder(timestamps, head_runs);
  builder.start(batch, module_id);
  for (const auto& f : frames) builder.append(batch, f);
  return batch;
}

// Serializes and parses `batch` first, so round trips also cover protobuf's packing.
std::vector<Frame> decode_over_wire(const v1::FrameBatch& batch) {
  v1::FrameBatch parsed;
  EXPECT_TRUE(parsed.ParseFromString(batch.SerializeAsString()));
  std::vector<Frame> out;
  EXPECT_EQ(decode_frame_batch(parsed, out), BatchError::none);
  return out;
}

std::vector<Frame> random_frames(std::mt19937& rng, std::size_t n, bool timestamps) {
  std::vector<Frame> frames;
  std::int64_t us = 1'700'000'000'000'000LL;
  for (std::size_t i = 0; i < n; ++i) {
    Frame f;
    const unsigned kind = rng() % 4;
    f.flags = kind == 1   ? FrameFlags::extended
              : kind == 2 ? FrameFlags::remote
              : kind == 3 && rng() % 2 != 0
                  ? static_cast<std::uint8_t>(FrameFlags::extended | FrameFlags::remote)
                  : 0;
    f.id = static_cast<std::uint32_t>(rng()) &
           (f.is_extended() ? can::kMaxExtendedId : can::kMaxStandardId);
    f.len = static_cast<std::uint8_t>(rng() % 9);
    for (auto& b : f.data) b = static_cast<std::uint8_t>(rng());
    if (timestamps) {
      // Mostly forward, sometimes backwards (frames merged from several queues).
      us += static_cast<std::int64_t>(rng() % 2000) - 100;
      f.timestamp = std::chrono::microseconds(us);
    }
    frames.push_back(f);
  }
  return frames;
}

// --- Round trips -------------------------------------------------------------------------------

TEST(FrameBatchCodec, RoundTripsEveryKindOfFrameWithEdgeIdsAndLengths) {
  std::vector<Frame> frames;
  for (std::uint8_t len = 0; len <= can::kMaxPayload; ++len) {
    for (std::uint32_t id : {0u, 1u, 0x400u, 0x7FEu, 0x7FFu}) {
      frames.push_back(frame(id, 0, len));
      frames.push_back(frame(id, FrameFlags::remote, len));
    }
    for (std::uint32_t id : {0u, 0x7FFu, 0x800u, 0x1234567u, 0x1FFFFFFEu, 0x1FFFFFFFu}) {
      frames.push_back(frame(id, FrameFlags::extended, len));
      frames.push_back(frame(id, FrameFlags::extended | FrameFlags::remote, len));
    }
  }
  const v1::FrameBatch batch = build(frames, false, 42);
  // Only standard data frames stay in the head: 9 lengths x (5 remote + 12 extended) escape.
  EXPECT_EQ(batch.escaped_can_id_size(), 9 * (5 + 12));
  EXPECT_EQ(batch.head().size(), 2 * frames.size());

  const auto out = decode_over_wire(batch);
  ASSERT_EQ(out.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(out[i], frames[i]) << i << ": " << can::to_string(frames[i]);
    EXPECT_EQ(out[i].timestamp.count(), 0) << i;  // not carried
  }
}

TEST(FrameBatchCodec, WritesTheDocumentedWireLayout) {
  const v1::FrameBatch batch = build(
      {
          Frame::standard(0x123, {0xDE, 0xAD, 0xBE}),                      // head 0x1923
          Frame::make(0x1234567, FrameFlags::extended, {0x01, 0x02}),      // 0x9000 + escape
          frame(0x7FF, FrameFlags::remote, 8),                             // 0xC000 + escape
          Frame::standard(0x7FF, {1, 2, 3, 4, 5, 6, 7, 8}),                // 0x47FF
          Frame::standard(0x000, {}),                                      // 0x0000
          frame(0x1FFFFFFF, FrameFlags::extended | FrameFlags::remote, 0)  // 0x8000 + escape
      },
      false, 7);
  EXPECT_EQ(batch.module_id(), 7u);
  EXPECT_EQ(batch.head(), head(0x1923) + head(0x9000) + head(0xC000) + head(0x47FF) + head(0x0000) +
                              head(0x8000));
  ASSERT_EQ(batch.escaped_can_id_size(), 3);
  EXPECT_EQ(batch.escaped_can_id(0), 0x81234567u);
  EXPECT_EQ(batch.escaped_can_id(1), 0x400007FFu);
  EXPECT_EQ(batch.escaped_can_id(2), 0xDFFFFFFFu);
  EXPECT_EQ(batch.data(), std::string("\xDE\xAD\xBE\x01\x02\x01\x02\x03\x04\x05\x06\x07\x08"));
  EXPECT_EQ(batch.timestamp_delta_us_size(), 0);
}

TEST(FrameBatchCodec, FullBatchOfStandardEightByteFramesCostsTenBytesPerFrame) {
  constexpr int kFrames = 64;
  v1::Payload payload;
  FrameBatchBuilder builder;
  builder.start(*payload.mutable_frames(), 1);
  for (int i = 0; i < kFrames; ++i) {
    const auto id = static_cast<std::uint32_t>(i * 0x7FF / (kFrames - 1));  // 0x000 .. 0x7FF
    const auto b = static_cast<std::uint8_t>(i);
    builder.append(*payload.mutable_frames(), Frame::standard(id, {b, 1, 2, 3, 4, 5, 6, 0xFF}));
  }
  const std::string wire = payload.SerializeAsString();
  ASSERT_EQ(wire.size(), payload.ByteSizeLong());
  const double per_frame = static_cast<double>(payload.ByteSizeLong()) / kFrames;
  std::cout << "[ measured ] " << payload.ByteSizeLong() << " bytes for " << kFrames
            << " frames = " << per_frame << " bytes/frame\n";
  RecordProperty("bytes_per_frame", std::to_string(per_frame));
  EXPECT_LE(per_frame, 10.25);

  v1::Payload parsed;
  ASSERT_TRUE(parsed.ParseFromString(wire));
  ASSERT_TRUE(parsed.has_frames());
  std::vector<Frame> out;
  ASSERT_EQ(decode_frame_batch(parsed.frames(), out), BatchError::none);
  ASSERT_EQ(out.size(), static_cast<std::size_t>(kFrames));
  EXPECT_EQ(out.front().id, 0x000u);
  EXPECT_EQ(out.back().id, 0x7FFu);
}

TEST(FrameBatchCodec, RoundTripsTimestampsToTheMicrosecond) {
  std::vector<Frame> frames;
  const std::int64_t base = 1'700'000'000'123'456LL;
  for (std::int64_t offset_us : {0LL, 0LL, 1LL, 250LL, 100LL, -5LL, 1'000'000'000LL}) {
    Frame f = Frame::standard(0x181, {1});
    f.timestamp = std::chrono::microseconds(base + offset_us);
    frames.push_back(f);
  }
  Frame unknown = Frame::standard(0x182, {});  // a frame built locally: timestamp zero
  frames.push_back(unknown);
  Frame sub_us = Frame::standard(0x183, {});
  sub_us.timestamp = std::chrono::nanoseconds(base * 1000 + 999);  // below the wire resolution
  frames.push_back(sub_us);

  const v1::FrameBatch batch = build(frames, true);
  ASSERT_EQ(batch.timestamp_delta_us_size(), static_cast<int>(frames.size()));
  EXPECT_EQ(batch.timestamp_delta_us(0), base);  // the first one is absolute
  EXPECT_EQ(batch.timestamp_delta_us(5), -105);

  const auto out = decode_over_wire(batch);
  ASSERT_EQ(out.size(), frames.size());
  for (std::size_t i = 0; i + 1 < frames.size(); ++i) {
    EXPECT_EQ(out[i].timestamp, frames[i].timestamp) << i;
  }
  EXPECT_EQ(out.back().timestamp, std::chrono::microseconds(base));  // truncated to whole µs
}

TEST(FrameBatchCodec, WithoutTimestampsTheColumnStaysEmpty) {
  Frame f = Frame::standard(0x181, {1, 2});
  f.timestamp = std::chrono::microseconds(123456);
  const v1::FrameBatch batch = build({f, f});
  EXPECT_EQ(batch.timestamp_delta_us_size(), 0);
  const auto out = decode_over_wire(batch);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0].timestamp.count(), 0);
}

TEST(FrameBatchCodec, StartBeginsAFreshBatchAndReusesCapacity) {
  std::mt19937 rng(11);
  const auto frames = random_frames(rng, 200, true);
  v1::FrameBatch batch;
  FrameBatchBuilder builder(true);
  builder.start(batch, 5);
  for (const auto& f : frames) builder.append(batch, f);
  const auto* head_buffer = batch.head().data();
  const auto* data_buffer = batch.data().data();
  const auto head_capacity = batch.head().capacity();
  const auto data_capacity = batch.data().capacity();
  const int escaped_capacity = batch.escaped_can_id().Capacity();
  const int timestamp_capacity = batch.timestamp_delta_us().Capacity();

  // The same frames again: start() must drop the old ones (and restart the delta chain, so the
  // first timestamp is absolute again) without giving up the grown buffers.
  builder.start(batch, 6);
  EXPECT_EQ(batch.head().size(), 0u);
  EXPECT_EQ(batch.escaped_can_id_size(), 0);
  EXPECT_EQ(batch.data().size(), 0u);
  EXPECT_EQ(batch.timestamp_delta_us_size(), 0);
  for (const auto& f : frames) builder.append(batch, f);
  EXPECT_EQ(batch.module_id(), 6u);
  EXPECT_EQ(batch.head().data(), head_buffer);
  EXPECT_EQ(batch.data().data(), data_buffer);
  EXPECT_EQ(batch.head().capacity(), head_capacity);
  EXPECT_EQ(batch.data().capacity(), data_capacity);
  EXPECT_EQ(batch.escaped_can_id().Capacity(), escaped_capacity);
  EXPECT_EQ(batch.timestamp_delta_us().Capacity(), timestamp_capacity);

  const auto out = decode_over_wire(batch);
  ASSERT_EQ(out.size(), frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    EXPECT_EQ(out[i], frames[i]) << i;
    EXPECT_EQ(out[i].timestamp, frames[i].timestamp) << i;
  }
}

TEST(FrameBatchCodec, ClampsFramesNoValidDecoderWouldAccept) {
  Frame too_long = Frame::standard(0x100, {1, 2, 3, 4, 5, 6, 7, 8});
  too_long.len = 200;  // must not read past data nor write bits 11-14 > 8
  Frame wide_std = Frame::standard(0x100, {9});
  wide_std.id = 0x1901;  // 13 bits in a standard frame: only the low 11 bits exist on a bus
  Frame wide_rtr = frame(0xF801, FrameFlags::remote, 0);
  Frame wide_ext = frame(0xE0000001, FrameFlags::extended, 0);
  const auto out = decode_over_wire(build({too_long, wide_std, wide_rtr, wide_ext}));
  ASSERT_EQ(out.size(), 4u);
  EXPECT_EQ(out[0], Frame::standard(0x100, {1, 2, 3, 4, 5, 6, 7, 8}));
  EXPECT_EQ(out[1], Frame::standard(0x101, {9}));
  EXPECT_EQ(out[2], frame(0x001, FrameFlags::remote, 0));
  EXPECT_EQ(out[3], frame(0x1, FrameFlags::extended, 0));
}

TEST(FrameBatchCodec, EmptyBatchDecodesToNothing) {
  std::vector<Frame> out{Frame::standard(1, {1})};
  EXPECT_EQ(decode_frame_batch(build({}), out), BatchError::none);
  EXPECT_EQ(out.size(), 1u);
  EXPECT_EQ(decode_frame_batch(v1::FrameBatch{}, out), BatchError::none);
  EXPECT_EQ(out.size(), 1u);
}

TEST(FrameBatchCodec, RoundTripsThousandsOfRandomBatches) {
  std::mt19937 rng(20240607);
  v1::FrameBatch batch;
  FrameBatchBuilder timed(true);
  FrameBatchBuilder untimed(false);
  std::vector<Frame> out;
  std::size_t frames_checked = 0;
  for (int round = 0; round < 4000; ++round) {
    const bool timestamps = rng() % 2 != 0;
    const auto frames = random_frames(rng, rng() % 100, timestamps);
    FrameBatchBuilder& builder = timestamps ? timed : untimed;
    const auto module_id = static_cast<std::uint32_t>(rng());
    builder.start(batch, module_id);  // one batch object reused, as the session does
    std::size_t payload = 0;
    int escapes = 0;
    for (const auto& f : frames) {
      builder.append(batch, f);
      payload += f.payload().size();
      escapes += f.is_extended() || f.is_remote() ? 1 : 0;
    }
    ASSERT_EQ(batch.head().size(), 2 * frames.size()) << round;
    ASSERT_EQ(batch.data().size(), payload) << round;
    ASSERT_EQ(batch.escaped_can_id_size(), escapes) << round;

    v1::FrameBatch parsed;
    ASSERT_TRUE(parsed.ParseFromString(batch.SerializeAsString())) << round;
    ASSERT_EQ(parsed.module_id(), module_id) << round;
    // Appends after whatever `out` already holds.
    out.assign(rng() % 3, Frame::standard(0x7E5, {0x5A}));
    const std::size_t before = out.size();
    ASSERT_EQ(decode_frame_batch(parsed, out), BatchError::none) << round;
    ASSERT_EQ(out.size(), before + frames.size()) << round;
    for (std::size_t i = 0; i < frames.size(); ++i) {
      ASSERT_EQ(out[before + i], frames[i]) << round << "/" << i;
      const auto expected = timestamps ? frames[i].timestamp : std::chrono::nanoseconds(0);
      ASSERT_EQ(out[before + i].timestamp, expected) << round << "/" << i;
    }
    frames_checked += frames.size();
  }
  RecordProperty("frames_checked", std::to_string(frames_checked));
}

// --- Head runs (protocol 2.6) -----------------------------------------------------------------

// `frames` with each frame repeated 1..4 times (runs of equal frames apart from the payload and
// timestamp), as a backlog of few COB-IDs leaves the outbox.
std::vector<Frame> with_repeats(std::mt19937& rng, const std::vector<Frame>& frames) {
  std::vector<Frame> out;
  for (const Frame& f : frames) {
    const unsigned copies = 1 + rng() % 4;
    for (unsigned c = 0; c < copies; ++c) {
      Frame copy = f;
      copy.data[0] = static_cast<std::uint8_t>(copy.data[0] + c);
      copy.timestamp += std::chrono::microseconds(c * 7);
      out.push_back(copy);
    }
  }
  return out;
}

TEST(FrameBatchHeadRuns, WritesTheDocumentedRunLayout) {
  const Frame ext = Frame::make(0x1234567, FrameFlags::extended, {0x01, 0x02});
  const Frame other_ext = Frame::make(0x1234568, FrameFlags::extended, {0x03, 0x04});
  const Frame rtr = frame(0x7FF, FrameFlags::remote, 8);
  // Word 0: a run of three; word 1: one frame; words 2 (a run of two) and 3: extended ids that
  // differ; word 4: a run of two remote frames; word 5: equal to word 0, but not adjacent.
  const std::vector<Frame> frames{Frame::standard(0x181, {1}),
                                  Frame::standard(0x181, {2}),
                                  Frame::standard(0x181, {3}),
                                  Frame::standard(0x182, {4}),
                                  ext,
                                  ext,
                                  other_ext,
                                  rtr,
                                  rtr,
                                  Frame::standard(0x181, {5})};
  const v1::FrameBatch batch = build(frames, false, 9, true);
  EXPECT_EQ(batch.head(), head(0x0981) + head(0x0982) + head(0x9000) + head(0x9000) + head(0xC000) +
                              head(0x0981));
  // (gap, repeats): word 0 + 2 more; word 2 (gap 2 after word 0) + 1; word 4 (gap 2) + 1.
  EXPECT_EQ(std::vector<std::uint32_t>(batch.head_runs().begin(), batch.head_runs().end()),
            (std::vector<std::uint32_t>{1, 2, 2, 1, 2, 1}));
  // One escaped entry per word, not per frame.
  EXPECT_EQ(
      std::vector<std::uint32_t>(batch.escaped_can_id().begin(), batch.escaped_can_id().end()),
      (std::vector<std::uint32_t>{0x81234567u, 0x81234568u, 0x400007FFu}));
  EXPECT_EQ(batch.data(), std::string("\x01\x02\x03\x04\x01\x02\x01\x02\x03\x04\x05"));

  const auto out = decode_over_wire(batch);
  EXPECT_EQ(out, frames);
}

TEST(FrameBatchHeadRuns, OffByDefaultAndThePlainFormIsUnchanged) {
  const std::vector<Frame> frames(5, Frame::standard(0x181, {1, 2, 3}));
  FrameBatchBuilder builder;
  EXPECT_FALSE(builder.head_runs());
  const v1::FrameBatch plain = build(frames);
  EXPECT_EQ(plain.head_runs_size(), 0);
  EXPECT_EQ(plain.head().size(), 2 * frames.size());
  // Field 7 never appears on the wire, so a 2.5 peer parses exactly what it always did.
  v1::FrameBatch old_view = plain;
  old_view.clear_head_runs();
  EXPECT_EQ(plain.SerializeAsString(), old_view.SerializeAsString());
  EXPECT_EQ(decode_over_wire(plain), frames);
}

TEST(FrameBatchHeadRuns, SetHeadRunsSwitchesTheFormBetweenBatches) {
  const std::vector<Frame> frames(4, Frame::standard(0x181, {7}));
  v1::FrameBatch batch;
  FrameBatchBuilder builder;
  builder.set_head_runs(true);
  builder.start(batch, 1);
  for (const auto& f : frames) builder.append(batch, f);
  EXPECT_EQ(batch.head(), head(0x0981));
  EXPECT_EQ(batch.head_runs_size(), 2);
  EXPECT_EQ(decode_over_wire(batch), frames);

  builder.set_head_runs(false);  // the peer turned out to be 2.5 on the next link
  builder.start(batch, 1);
  for (const auto& f : frames) builder.append(batch, f);
  EXPECT_EQ(batch.head_runs_size(), 0);
  EXPECT_EQ(batch.head().size(), 8u);
  EXPECT_EQ(decode_over_wire(batch), frames);
}

// Takes every payload a FrameOutbox produces (the outbox's own tests have the full fake).
class CollectingSink : public backbone::PayloadSink {
 public:
  std::size_t room() const override { return room_; }
  bool reliable_room(std::size_t) const override { return true; }
  void send_reliable(std::string payload) override { take(payload); }
  void send_unreliable(std::span<const std::uint8_t> p) override {
    take(std::string(reinterpret_cast<const char*>(p.data()), p.size()));
  }
  std::vector<v1::FrameBatch> batches;

 private:
  void take(const std::string& payload) {
    room_ = payload.size() < room_ ? room_ - payload.size() : 0;
    v1::Payload parsed;
    EXPECT_TRUE(parsed.ParseFromString(payload));
    batches.push_back(parsed.frames());
  }
  std::size_t room_ = 4096;
};

// What the gateway and the surface do on every link: head runs only when the peer's hello says
// it decodes them; the same backlog crosses in either form.
TEST(FrameBatchHeadRuns, TheOutboxBuildsTheFormItsPeerDecodes) {
  for (const bool runs : {false, true}) {
    SCOPED_TRACE(runs ? "peer at 2.6" : "peer at 2.5");
    FrameOutbox outbox(FrameOutbox::Options{});
    outbox.set_head_runs(runs);
    std::vector<Frame> backlog;
    for (std::uint8_t i = 0; i < 20; ++i) {
      backlog.push_back(Frame::standard(0x081, {i, 1, 2, 3, 4, 5, 6, 7}));  // EMCY: reliable
      ASSERT_TRUE(outbox.push(1, backlog.back(), {}, FrameOutbox::Clock::time_point{}));
    }
    CollectingSink sink;
    outbox.produce(sink);
    ASSERT_EQ(sink.batches.size(), 1u);
    const v1::FrameBatch& batch = sink.batches.front();
    EXPECT_EQ(batch.head_runs_size(), runs ? 2 : 0);
    EXPECT_EQ(batch.head().size(), runs ? 2u : 40u);
    std::vector<Frame> out;
    ASSERT_EQ(decode_frame_batch(batch, out), BatchError::none);
    EXPECT_EQ(out, backlog);
  }
}

TEST(FrameBatchHeadRuns, CostIsWhatAppendAddsToTheColumns) {
  std::mt19937 rng(7);
  for (const bool runs : {false, true}) {
    v1::FrameBatch batch;
    FrameBatchBuilder builder(false, runs);
    builder.start(batch, 1);
    std::size_t costs = 0;
    for (const Frame& f : with_repeats(rng, random_frames(rng, 200, false))) {
      costs += builder.cost(f);
      builder.append(batch, f);
    }
    // head, data, escaped ids (at most 5 bytes each) and pairs (1-byte varints here).
    std::size_t columns = batch.head().size() + batch.data().size() +
                          5 * static_cast<std::size_t>(batch.escaped_can_id_size());
    for (std::uint32_t v : batch.head_runs()) columns += v < 128 ? 1 : 2;
    EXPECT_GE(costs + 8, columns) << runs;
    EXPECT_LE(costs, columns + 8) << runs;
  }
}

TEST(FrameBatchHeadRuns, ABurstOfOneCobIdCostsItsPayloadBytes) {
  constexpr int kFrames = 47;  // what a 512-byte batch of the serial sample config holds
  v1::Payload payload;
  FrameBatchBuilder builder(false, true);
  builder.start(*payload.mutable_frames(), 1);
  for (int i = 0; i < kFrames; ++i) {
    const auto b = static_cast<std::uint8_t>(i);
    builder.append(*payload.mutable_frames(), Frame::standard(0x181, {b, 1, 2, 3, 4, 5, 6, b}));
  }
  const double per_frame = static_cast<double>(payload.ByteSizeLong()) / kFrames;
  std::cout << "[ measured ] " << payload.ByteSizeLong() << " bytes for " << kFrames
            << " frames of one COB-ID = " << per_frame << " bytes/frame\n";
  RecordProperty("bytes_per_frame", std::to_string(per_frame));
  EXPECT_LE(per_frame, 8.4);  // plain: 10.3
  std::vector<Frame> out;
  ASSERT_EQ(decode_frame_batch(payload.frames(), out), BatchError::none);
  EXPECT_EQ(out.size(), static_cast<std::size_t>(kFrames));
}

TEST(FrameBatchHeadRuns, RoundTripsRandomBatchesInBothFormsAndRunsNeverCostMuchMore) {
  std::mt19937 rng(20261202);
  v1::FrameBatch plain;
  v1::FrameBatch runs;
  std::size_t repeated = 0;
  for (int round = 0; round < 2000; ++round) {
    const bool timestamps = rng() % 2 != 0;
    auto frames = random_frames(rng, rng() % 40, timestamps);
    if (rng() % 4 != 0) frames = with_repeats(rng, frames);
    FrameBatchBuilder p(timestamps, false);
    FrameBatchBuilder r(timestamps, true);
    p.start(plain, 5);
    r.start(runs, 5);
    for (const auto& f : frames) {
      p.append(plain, f);
      r.append(runs, f);
    }
    ASSERT_EQ(plain.head_runs_size(), 0) << round;
    ASSERT_EQ(plain.head().size(), 2 * frames.size()) << round;
    repeated += plain.head().size() / 2 - runs.head().size() / 2;
    // With gaps below 128 a pair costs two varint bytes and saves at least one head word, so
    // the run form is never more than the field's tag and length larger.
    ASSERT_LE(runs.ByteSizeLong(), plain.ByteSizeLong() + 2) << round;
    for (const v1::FrameBatch* b : {&plain, &runs}) {
      const auto out = decode_over_wire(*b);
      ASSERT_EQ(out.size(), frames.size()) << round;
      for (std::size_t i = 0; i < frames.size(); ++i) {
        ASSERT_EQ(out[i], frames[i]) << round << "/" << i;
        const auto expected = timestamps ? frames[i].timestamp : std::chrono::nanoseconds(0);
        ASSERT_EQ(out[i].timestamp, expected) << round << "/" << i;
      }
    }
  }
  EXPECT_GT(repeated, 10000u);  // the runs form was exercised, not just allowed
}

// --- Refusals ----------------------------------------------------------------------------------

// Decodes into an `out` that already holds frames and checks the refusal leaves it untouched.
BatchError refuse(const v1::FrameBatch& batch) {
  const std::vector<Frame> before{Frame::standard(0x181, {1, 2}),
                                  frame(0x42, FrameFlags::remote, 3)};
  std::vector<Frame> out = before;
  const BatchError e = decode_frame_batch(batch, out);
  if (e != BatchError::none) {
    EXPECT_EQ(out, before) << "output changed on " << to_string(e);
  }
  return e;
}

// A well-formed batch to break: a standard data frame, an escaped extended frame, a remote one.
v1::FrameBatch good() {
  v1::FrameBatch b;
  b.set_module_id(3);
  b.set_head(head(0x1123) + head(0x8800) + head(0xC000));  // 0x123 len 2, ext len 1, rtr dlc 8
  b.add_escaped_can_id(0x80012345);
  b.add_escaped_can_id(0x40000700);
  b.set_data(
      "ab"
      "c");
  return b;
}

TEST(FrameBatchCodecRefuses, NothingInTheBaseBatch) {
  EXPECT_EQ(refuse(good()), BatchError::none);
  std::vector<Frame> out;
  ASSERT_EQ(decode_frame_batch(good(), out), BatchError::none);
  ASSERT_EQ(out.size(), 3u);
  EXPECT_EQ(out[0], Frame::standard(0x123, {'a', 'b'}));
  EXPECT_EQ(out[1], Frame::make(0x12345, FrameFlags::extended, {'c'}));
  EXPECT_EQ(out[2], frame(0x700, FrameFlags::remote, 8));
}

TEST(FrameBatchCodecRefuses, AnOddLengthHead) {
  v1::FrameBatch b = good();
  b.mutable_head()->push_back('\0');
  EXPECT_EQ(refuse(b), BatchError::column_mismatch);
  b.set_head(std::string(1, '\x23'));
  b.clear_escaped_can_id();
  b.clear_data();
  EXPECT_EQ(refuse(b), BatchError::column_mismatch);
}

TEST(FrameBatchCodecRefuses, TimestampsNotOnePerFrame) {
  v1::FrameBatch b = good();
  b.add_timestamp_delta_us(1);
  b.add_timestamp_delta_us(2);
  EXPECT_EQ(refuse(b), BatchError::column_mismatch);
  b.add_timestamp_delta_us(3);
  EXPECT_EQ(refuse(b), BatchError::none);
  b.add_timestamp_delta_us(4);
  EXPECT_EQ(refuse(b), BatchError::column_mismatch);
}

TEST(FrameBatchCodecRefuses, LengthsAboveEight) {
  for (std::uint16_t len = 9; len <= 15; ++len) {
    v1::FrameBatch data_frame = good();  // standard data frame (no payload for it at all)
    data_frame.set_head(head(static_cast<std::uint16_t>(0x123 | len << 11)));
    data_frame.clear_escaped_can_id();
    data_frame.set_data(std::string(len, 'x'));
    EXPECT_EQ(refuse(data_frame), BatchError::bad_length) << len;

    v1::FrameBatch remote = good();  // a remote frame's requested DLC is held to 8 as well
    remote.set_head(head(0x1123) + head(0x8800) +
                    head(static_cast<std::uint16_t>(0x8000 | len << 11)));
    EXPECT_EQ(refuse(remote), BatchError::bad_length) << len;
  }
}

TEST(FrameBatchCodecRefuses, EscapesWithoutEntriesAndEntriesWithoutEscapes) {
  v1::FrameBatch missing = good();
  missing.mutable_escaped_can_id()->RemoveLast();
  EXPECT_EQ(refuse(missing), BatchError::escape_mismatch);
  missing.clear_escaped_can_id();
  EXPECT_EQ(refuse(missing), BatchError::escape_mismatch);

  v1::FrameBatch extra = good();
  extra.add_escaped_can_id(0x80000001);
  EXPECT_EQ(refuse(extra), BatchError::escape_mismatch);

  v1::FrameBatch unescaped = good();
  unescaped.set_head(head(0x1123));
  unescaped.set_data("ab");
  EXPECT_EQ(refuse(unescaped), BatchError::escape_mismatch);
}

TEST(FrameBatchCodecRefuses, StandardIdsAboveElevenBits) {
  v1::FrameBatch b = good();
  b.set_escaped_can_id(1, 0x40000800);  // standard remote frame with a 12-bit id
  EXPECT_EQ(refuse(b), BatchError::bad_id);
  b.set_escaped_can_id(1, 0x1FFFFFFF);  // standard data frame, escaped needlessly, 29-bit id
  b.set_data(
      "abc"
      "12345678");
  EXPECT_EQ(refuse(b), BatchError::bad_id);
  b.set_escaped_can_id(1, 0x7FF);  // a needless escape is still a valid standard frame
  EXPECT_EQ(refuse(b), BatchError::none);
}

TEST(FrameBatchCodecRefuses, EscapesThatAlsoCarryIdBits) {
  v1::FrameBatch b = good();
  b.set_head(head(0x1123) + head(0x8801) + head(0xC000));
  EXPECT_EQ(refuse(b), BatchError::bad_id);
  b.set_head(head(0x1123) + head(0x8800) + head(0xC400));
  EXPECT_EQ(refuse(b), BatchError::bad_id);
}

TEST(FrameBatchCodecRefuses, TheErrorFrameFlag) {
  v1::FrameBatch b = good();
  b.set_escaped_can_id(0, 0xA0012345);  // CAN_ERR_FLAG: the wire carries no error frames
  EXPECT_EQ(refuse(b), BatchError::bad_id);
}

TEST(FrameBatchCodecRefuses, DataThatIsNotExactlyThePayloads) {
  v1::FrameBatch b = good();
  b.set_data("ab");
  EXPECT_EQ(refuse(b), BatchError::data_size_mismatch);
  b.set_data("abcd");  // the remote frame's DLC 8 must not claim payload bytes
  EXPECT_EQ(refuse(b), BatchError::data_size_mismatch);
  b.set_data(std::string("abc") + std::string(8, 'r'));
  EXPECT_EQ(refuse(b), BatchError::data_size_mismatch);
  b.clear_data();
  EXPECT_EQ(refuse(b), BatchError::data_size_mismatch);
}

TEST(FrameBatchCodecRefuses, TimestampsBeyondWhatNanosecondsHold) {
  constexpr std::int64_t kMax = std::numeric_limits<std::int64_t>::max();
  constexpr std::int64_t kMin = std::numeric_limits<std::int64_t>::min();
  const std::int64_t max_us = std::chrono::nanoseconds::max().count() / 1000;
  const auto with = [](std::vector<std::int64_t> deltas) {
    v1::FrameBatch b = good();
    for (auto d : deltas) b.add_timestamp_delta_us(d);
    return b;
  };
  EXPECT_EQ(refuse(with({kMax, 0, 0})), BatchError::bad_timestamp);
  EXPECT_EQ(refuse(with({kMin, 0, 0})), BatchError::bad_timestamp);
  EXPECT_EQ(refuse(with({max_us, 1, 0})), BatchError::bad_timestamp);
  EXPECT_EQ(refuse(with({0, 0, max_us + 1})), BatchError::bad_timestamp);
  EXPECT_EQ(refuse(with({max_us, kMin, 0})), BatchError::bad_timestamp);
  EXPECT_EQ(refuse(with({max_us, 0, -max_us})), BatchError::none);
}

// good() with the standard frame a run of three and the extended one a run of two.
v1::FrameBatch good_runs() {
  v1::FrameBatch b = good();
  b.add_head_runs(1);  // word 0
  b.add_head_runs(2);
  b.add_head_runs(1);  // word 1
  b.add_head_runs(1);
  b.set_data(
      "ababab"
      "cc");
  return b;
}

TEST(FrameBatchCodecRefuses, NothingInTheBaseRunBatch) {
  EXPECT_EQ(refuse(good_runs()), BatchError::none);
  std::vector<Frame> out;
  ASSERT_EQ(decode_frame_batch(good_runs(), out), BatchError::none);
  const Frame std_frame = Frame::standard(0x123, {'a', 'b'});
  const Frame ext_frame = Frame::make(0x12345, FrameFlags::extended, {'c'});
  EXPECT_EQ(out, (std::vector<Frame>{std_frame, std_frame, std_frame, ext_frame, ext_frame,
                                     frame(0x700, FrameFlags::remote, 8)}));
}

TEST(FrameBatchCodecRefuses, RunsThatAreNotPairsOrPointNowhere) {
  v1::FrameBatch odd = good_runs();
  odd.add_head_runs(1);
  EXPECT_EQ(refuse(odd), BatchError::bad_run);

  v1::FrameBatch zero_gap = good_runs();
  zero_gap.set_head_runs(2, 0);  // the same word twice
  EXPECT_EQ(refuse(zero_gap), BatchError::bad_run);
  zero_gap.set_head_runs(0, 0);  // before the first word
  EXPECT_EQ(refuse(zero_gap), BatchError::bad_run);

  v1::FrameBatch past_end = good_runs();
  past_end.set_head_runs(2, 3);  // word 3 of 3 words (0..2)
  EXPECT_EQ(refuse(past_end), BatchError::bad_run);
  past_end.set_head_runs(2, 0xFFFFFFFF);  // would wrap a 32-bit index back into range
  EXPECT_EQ(refuse(past_end), BatchError::bad_run);
  past_end.set_head_runs(2, 2);  // word 2: the remote frame, a run of 2 now
  past_end.set_data("abababc");  // and the extended frame a single one
  EXPECT_EQ(refuse(past_end), BatchError::none);

  v1::FrameBatch no_repeats = good_runs();
  no_repeats.set_head_runs(1, 0);
  EXPECT_EQ(refuse(no_repeats), BatchError::bad_run);

  v1::FrameBatch runs_without_head = good_runs();
  runs_without_head.clear_head();
  runs_without_head.clear_escaped_can_id();
  runs_without_head.clear_data();
  EXPECT_EQ(refuse(runs_without_head), BatchError::bad_run);
}

TEST(FrameBatchCodecRefuses, RunsBeyondTheFrameBound) {
  // Zero-length frames cost nothing in a run: only the count bounds what a batch decodes to.
  v1::FrameBatch b;
  b.set_head(head(0x0181));  // 0x181, len 0
  b.add_head_runs(1);
  b.add_head_runs(static_cast<std::uint32_t>(kMaxBatchFrames - 1));
  EXPECT_EQ(refuse(b), BatchError::none);
  b.set_head_runs(1, static_cast<std::uint32_t>(kMaxBatchFrames));
  EXPECT_EQ(refuse(b), BatchError::too_many_frames);
  b.set_head_runs(1, 0xFFFFFFFF);
  EXPECT_EQ(refuse(b), BatchError::too_many_frames);
  // Two runs whose sum wraps 32 bits.
  b.set_head(head(0x0181) + head(0x0182));
  b.set_head_runs(1, 0x80000000u);
  b.add_head_runs(1);
  b.add_head_runs(0x80000000u);
  EXPECT_EQ(refuse(b), BatchError::too_many_frames);
  // And the plain form: more head words than the bound.
  v1::FrameBatch wide;
  wide.set_head(std::string(2 * (kMaxBatchFrames + 1), '\0'));
  EXPECT_EQ(refuse(wide), BatchError::too_many_frames);
}

TEST(FrameBatchCodecRefuses, RunColumnsThatDoNotCountTheRepeats) {
  v1::FrameBatch per_word_data = good_runs();
  per_word_data.set_data("abc");  // one payload per word instead of per frame
  EXPECT_EQ(refuse(per_word_data), BatchError::data_size_mismatch);

  v1::FrameBatch per_word_stamps = good_runs();
  for (int i = 0; i < 3; ++i) per_word_stamps.add_timestamp_delta_us(1);
  EXPECT_EQ(refuse(per_word_stamps), BatchError::column_mismatch);
  for (int i = 0; i < 3; ++i) per_word_stamps.add_timestamp_delta_us(1);
  EXPECT_EQ(refuse(per_word_stamps), BatchError::none);

  v1::FrameBatch per_frame_escapes = good_runs();  // a run shares one escaped entry
  per_frame_escapes.add_escaped_can_id(0x80012345);
  EXPECT_EQ(refuse(per_frame_escapes), BatchError::escape_mismatch);

  v1::FrameBatch late_bad_stamp = good_runs();  // the bad timestamp is a repeat's
  for (std::int64_t d :
       std::vector<std::int64_t>{0, 0, std::numeric_limits<std::int64_t>::max(), 0, 0, 0}) {
    late_bad_stamp.add_timestamp_delta_us(d);
  }
  EXPECT_EQ(refuse(late_bad_stamp), BatchError::bad_timestamp);
}

TEST(FrameBatchCodecRefuses, ABadLastFrameAfterManyGoodOnes) {
  std::mt19937 rng(3);
  v1::FrameBatch b = build(random_frames(rng, 500, true));
  b.mutable_head()->back() = static_cast<char>(b.head().back() | 0x78);  // last length -> 15
  EXPECT_EQ(refuse(b), BatchError::bad_length);
}

// Random corruption of valid batches: every outcome is allowed except a crash, UB (the
// sanitizers watch) or a refusal that changed the output.
TEST(FrameBatchCodecRefuses, RandomlyCorruptedBatchesCleanly) {
  std::mt19937 rng(99);
  std::set<BatchError> seen;
  for (int round = 0; round < 3000; ++round) {
    const bool runs = rng() % 2 != 0;
    v1::FrameBatch b = build(with_repeats(rng, random_frames(rng, 1 + rng() % 20, rng() % 2 != 0)),
                             false, 1, runs);
    switch (rng() % (runs ? 8 : 6)) {
      case 0:
        if (!b.head().empty())
          (*b.mutable_head())[rng() % b.head().size()] ^= static_cast<char>(1u << (rng() % 8));
        break;
      case 1:
        b.mutable_head()->push_back(static_cast<char>(rng()));
        break;
      case 2:
        b.add_escaped_can_id(static_cast<std::uint32_t>(rng()));
        break;
      case 3:
        if (b.escaped_can_id_size() != 0) {
          b.set_escaped_can_id(static_cast<int>(rng() % b.escaped_can_id_size()),
                               static_cast<std::uint32_t>(rng()));
        }
        break;
      case 4:
        b.mutable_data()->resize(rng() % (b.data().size() + 4));
        break;
      case 5:
        b.add_timestamp_delta_us(static_cast<std::int64_t>(rng()) << (rng() % 40));
        break;
      case 6:
        if (b.head_runs_size() != 0) {
          const int i = static_cast<int>(rng() % b.head_runs_size());
          b.set_head_runs(i, rng() % 3 == 0
                                 ? static_cast<std::uint32_t>(rng())
                                 : b.head_runs(i) + static_cast<std::uint32_t>(rng() % 3) - 1);
        }
        break;
      case 7:
        b.add_head_runs(static_cast<std::uint32_t>(rng() % 4));
        break;
    }
    seen.insert(refuse(b));
  }
  // The corruptions reach every refusal (and sometimes still decode).
  for (BatchError e :
       {BatchError::none, BatchError::column_mismatch, BatchError::bad_length, BatchError::bad_id,
        BatchError::data_size_mismatch, BatchError::escape_mismatch, BatchError::bad_run}) {
    EXPECT_TRUE(seen.count(e) != 0) << to_string(e);
  }
}

TEST(FrameBatchCodec, NamesEveryError) {
  std::set<std::string_view> names;
  for (BatchError e :
       {BatchError::none, BatchError::column_mismatch, BatchError::bad_length, BatchError::bad_id,
        BatchError::data_size_mismatch, BatchError::escape_mismatch, BatchError::bad_timestamp,
        BatchError::bad_run, BatchError::too_many_frames}) {
    EXPECT_NE(to_string(e), "unknown");
    names.insert(to_string(e));
  }
  EXPECT_EQ(names.size(), 9u);
}

}  // namespace
}  // namespace canbridge::bridge
