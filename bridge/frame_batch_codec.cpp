#include "bridge/frame_batch_codec.hpp"

#include <algorithm>
#include <chrono>
#include <string>

namespace canbridge::bridge {

namespace {
// SocketCAN's can_id flag bits, used in escaped_can_id so an entry reads like struct can_frame.
constexpr std::uint32_t kEffFlag = 0x80000000u;
constexpr std::uint32_t kRtrFlag = 0x40000000u;
// CAN_ERR_FLAG: the wire does not carry error frames, so an entry with it set is malformed.
constexpr std::uint32_t kErrFlag = 0x20000000u;
constexpr std::uint32_t kIdMask = 0x1FFFFFFFu;

// Head word layout (canbridge.proto, FrameBatch.head).
constexpr std::uint16_t kHeadIdMask = 0x07FF;
constexpr unsigned kHeadLengthShift = 11;
constexpr std::uint16_t kHeadLengthMask = 0x0F;
constexpr std::uint16_t kHeadEscape = 0x8000;
constexpr std::size_t kHeadBytes = 2;

// The bounds a running timestamp in microseconds may take so that converting it to
// std::chrono::nanoseconds cannot overflow (a hostile delta column must not cause UB).
constexpr std::int64_t kMaxUs = std::chrono::nanoseconds::max().count() / 1000;
constexpr std::int64_t kMinUs = std::chrono::nanoseconds::min().count() / 1000;

// The head is protobuf `bytes`, so its byte order is ours to fix: little endian, written here
// rather than through canopen/little_endian.hpp so the codec does not depend on CANopen.
std::uint16_t head_word(const std::string& head, std::size_t frame) {
  const auto lo = static_cast<unsigned char>(head[frame * kHeadBytes]);
  const auto hi = static_cast<unsigned char>(head[frame * kHeadBytes + 1]);
  return static_cast<std::uint16_t>(lo | (hi << 8));
}

// Fills id, flags and len of `f` from one head word (consuming an escaped_can_id entry when the
// word escapes); the payload and timestamp are the caller's.
BatchError parse_head(std::uint16_t word, const v1::FrameBatch& batch, int& next_escape,
                      can::Frame& f) {
  const auto len = static_cast<std::uint8_t>((word >> kHeadLengthShift) & kHeadLengthMask);
  if (len > can::kMaxPayload) return BatchError::bad_length;
  f.len = len;
  if ((word & kHeadEscape) == 0) {
    f.id = word & kHeadIdMask;
    f.flags = 0;
    return BatchError::none;
  }
  if (next_escape >= batch.escaped_can_id_size()) return BatchError::escape_mismatch;
  // Identifier bits beside an escape would leave two candidate ids; refuse rather than guess.
  if ((word & kHeadIdMask) != 0) return BatchError::bad_id;
  const std::uint32_t can_id = batch.escaped_can_id(next_escape++);
  if ((can_id & kErrFlag) != 0) return BatchError::bad_id;
  f.flags = static_cast<std::uint8_t>(((can_id & kEffFlag) ? can::FrameFlags::extended : 0) |
                                      ((can_id & kRtrFlag) ? can::FrameFlags::remote : 0));
  f.id = can_id & kIdMask;
  if (!f.is_extended() && f.id > can::kMaxStandardId) return BatchError::bad_id;
  return BatchError::none;
}

// Checks head_runs against the `words` head words and counts the frames they stand for.
BatchError count_frames(const v1::FrameBatch& batch, std::size_t words, std::size_t& frames) {
  if (words > kMaxBatchFrames) return BatchError::too_many_frames;
  const auto& runs = batch.head_runs();
  if (runs.size() % 2 != 0) return BatchError::bad_run;
  frames = words;
  std::size_t base = 0;  // the word after the previous pair's word
  for (int p = 0; p < runs.size(); p += 2) {
    const std::uint32_t gap = runs.Get(p);
    const std::uint32_t repeats = runs.Get(p + 1);
    // Compared before adding, so a hostile gap cannot wrap the index back into range.
    if (gap == 0 || gap > words - base || repeats == 0) return BatchError::bad_run;
    base += gap;
    if (repeats > kMaxBatchFrames - frames) return BatchError::too_many_frames;
    frames += repeats;
  }
  return BatchError::none;
}

// Walks head_runs (already checked by count_frames) alongside the head words.
class RunCursor {
 public:
  explicit RunCursor(const v1::FrameBatch& batch) : runs_(batch.head_runs()) { seek(0); }

  // The frames head word `word` stands for; words are asked for in order, each once.
  std::size_t frames_of(std::size_t word) {
    if (word != next_word_) return 1;
    const std::size_t frames = 1 + std::size_t{runs_.Get(pair_ + 1)};
    pair_ += 2;
    seek(word + 1);
    return frames;
  }

 private:
  void seek(std::size_t base) {
    next_word_ = pair_ < runs_.size() ? base + runs_.Get(pair_) - 1 : kNone;
  }

  static constexpr std::size_t kNone = static_cast<std::size_t>(-1);
  const google::protobuf::RepeatedField<std::uint32_t>& runs_;
  int pair_ = 0;
  std::size_t next_word_ = kNone;
};

// Advances the running timestamp `us` by `delta`, or fails if it would leave [kMinUs, kMaxUs].
bool advance(std::int64_t& us, std::int64_t delta) {
  // Both differences fit in int64 because us itself is within the bounds.
  if (delta > kMaxUs - us || delta < kMinUs - us) return false;
  us += delta;
  return true;
}
}  // namespace

void FrameBatchBuilder::start(v1::FrameBatch& batch, std::uint32_t module_id) {
  batch.Clear();
  batch.set_module_id(module_id);
  last_us_ = 0;
  have_last_ = false;
  words_ = 0;
  run_base_ = 0;
  last_in_run_ = false;
}

namespace {
// A frame's head word and (when it escapes) SocketCAN can_id, clamped as append() documents.
struct Head {
  std::uint16_t word;
  bool escaped;
  std::uint32_t can_id;
  std::uint8_t len;
};

Head head_of(const can::Frame& frame) {
  // Clamped so a malformed Frame never reads past frame.data nor poisons the receiver's batch.
  const auto len = static_cast<std::uint8_t>(std::min<std::size_t>(frame.len, can::kMaxPayload));
  Head h{static_cast<std::uint16_t>(len << kHeadLengthShift),
         frame.is_extended() || frame.is_remote(), 0, len};
  if (h.escaped) {
    h.can_id = frame.id & (frame.is_extended() ? kIdMask : can::kMaxStandardId);
    if (frame.is_extended()) h.can_id |= kEffFlag;
    if (frame.is_remote()) h.can_id |= kRtrFlag;
    h.word |= kHeadEscape;
  } else {
    h.word |= static_cast<std::uint16_t>(frame.id & kHeadIdMask);
  }
  return h;
}
}  // namespace

std::size_t FrameBatchBuilder::cost(const can::Frame& frame) const {
  const Head h = head_of(frame);
  const std::size_t payload = frame.is_remote() ? 0 : h.len;
  if (runs_ && have_last_ && h.word == last_word_ && (!h.escaped || h.can_id == last_can_id_)) {
    return payload + (last_in_run_ ? 0 : 2);  // a new pair: gap and repeats, one byte each
  }
  return kHeadBytes + payload + (h.escaped ? 5 : 0);
}

void FrameBatchBuilder::append(v1::FrameBatch& batch, const can::Frame& frame) {
  const Head h = head_of(frame);
  const auto len = h.len;
  const auto word = h.word;
  const bool escaped = h.escaped;
  const std::uint32_t can_id = h.can_id;
  if (runs_ && have_last_ && word == last_word_ && (!escaped || can_id == last_can_id_)) {
    // The same head again: one more repeat of the latest word, which gets a pair if it has none.
    auto& runs = *batch.mutable_head_runs();
    if (last_in_run_) {
      runs.Set(runs.size() - 1, runs.Get(runs.size() - 1) + 1);
    } else {
      const std::size_t word_index = words_ - 1;
      runs.Add(static_cast<std::uint32_t>(word_index - run_base_ + 1));
      runs.Add(1);
      run_base_ = word_index + 1;
      last_in_run_ = true;
    }
  } else {
    if (escaped) batch.add_escaped_can_id(can_id);
    std::string& head = *batch.mutable_head();
    head.push_back(static_cast<char>(word & 0xFF));
    head.push_back(static_cast<char>(word >> 8));
    ++words_;
    have_last_ = true;
    last_word_ = word;
    last_can_id_ = can_id;
    last_in_run_ = false;
  }
  if (!frame.is_remote()) {
    batch.mutable_data()->append(reinterpret_cast<const char*>(frame.data.data()), len);
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
    case BatchError::escape_mismatch:
      return "escape-mismatch";
    case BatchError::bad_timestamp:
      return "bad-timestamp";
    case BatchError::bad_run:
      return "bad-run";
    case BatchError::too_many_frames:
      return "too-many-frames";
  }
  return "unknown";
}

BatchError decode_frame_batch(const v1::FrameBatch& batch, std::vector<can::Frame>& out) {
  const std::string& head = batch.head();
  const std::string& data = batch.data();
  if (head.size() % kHeadBytes != 0) return BatchError::column_mismatch;
  const std::size_t words = head.size() / kHeadBytes;
  std::size_t n = 0;
  if (const BatchError e = count_frames(batch, words, n); e != BatchError::none) return e;
  const bool timed = batch.timestamp_delta_us_size() != 0;
  if (timed && static_cast<std::size_t>(batch.timestamp_delta_us_size()) != n) {
    return BatchError::column_mismatch;
  }

  // Pass 1 validates everything, so a bad batch neither leaves partial output nor makes `out`
  // grow (a large hostile head would otherwise cost ~12 bytes of Frame per head byte).
  {
    int next_escape = 0;
    std::size_t payload_bytes = 0;
    std::int64_t us = 0;
    int stamp = 0;
    RunCursor runs(batch);
    can::Frame f;
    for (std::size_t i = 0; i < words; ++i) {
      if (const BatchError e = parse_head(head_word(head, i), batch, next_escape, f);
          e != BatchError::none) {
        return e;
      }
      const std::size_t count = runs.frames_of(i);
      if (!f.is_remote()) payload_bytes += f.len * count;
      for (std::size_t k = 0; timed && k < count; ++k) {
        if (!advance(us, batch.timestamp_delta_us(stamp++))) return BatchError::bad_timestamp;
      }
    }
    if (next_escape != batch.escaped_can_id_size()) return BatchError::escape_mismatch;
    if (payload_bytes != data.size()) return BatchError::data_size_mismatch;
  }

  // Pass 2 cannot fail: it repeats pass 1's parse and copies payloads and timestamps.
  out.reserve(out.size() + n);
  int next_escape = 0;
  std::size_t offset = 0;
  std::int64_t us = 0;
  int stamp = 0;
  RunCursor runs(batch);
  for (std::size_t i = 0; i < words; ++i) {
    can::Frame f;
    parse_head(head_word(head, i), batch, next_escape, f);
    const std::size_t count = runs.frames_of(i);
    for (std::size_t k = 0; k < count; ++k) {
      if (!f.is_remote()) {
        std::copy_n(data.data() + offset, f.len, reinterpret_cast<char*>(f.data.data()));
        offset += f.len;
      }
      if (timed) {
        advance(us, batch.timestamp_delta_us(stamp++));
        f.timestamp = std::chrono::microseconds(us);
      }
      out.push_back(f);
    }
  }
  return BatchError::none;
}

std::optional<std::string> decode_frame_payload(std::span<const std::uint8_t> bytes,
                                                v1::Payload& payload,
                                                std::vector<can::Frame>& frames) {
  frames.clear();
  if (!payload.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())) ||
      !payload.has_frames()) {
    return std::string("not a frame batch");
  }
  if (const BatchError err = decode_frame_batch(payload.frames(), frames);
      err != BatchError::none) {
    return "malformed frame batch (" + std::string(to_string(err)) + ")";
  }
  return std::nullopt;
}

}  // namespace canbridge::bridge
