// The wire format of backbone messages on a serial line (COBS-stuffed payload + CRC-32C, 0x00
// delimited), and the receiver that recovers intact messages from a noisy, arbitrarily split
// byte stream.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "backbone/cobs.hpp"

namespace canbridge::backbone {

// Ends every frame. COBS keeps it out of the frame body, so after noise or a cut a receiver
// finds the start of the next frame right after the next one.
inline constexpr std::uint8_t kFrameDelimiter = 0;
inline constexpr std::size_t kFrameCrcSize = 4;
// Payload sizes above this are refused by SerialDeframer (keeps its size arithmetic in range).
inline constexpr std::size_t kMaxSerialPayload = std::size_t{1} << 30;

// Bytes one frame of an n-byte payload occupies on the line at most, delimiter included.
constexpr std::size_t serial_frame_max_size(std::size_t payload_size) noexcept {
  return cobs_max_encoded_size(payload_size + kFrameCrcSize) + 1;
}

// Appends one frame: COBS(payload || crc32c(payload) as 4 bytes little endian) 0x00.
// A sender that may have been cut off mid-frame (e.g. after reopening the port) should write a
// single kFrameDelimiter first: the receiver then drops its partial frame and counts it once,
// instead of merging it with this frame and losing both.
void append_serial_frame(std::string& out, std::span<const std::uint8_t> payload);

// What a SerialDeframer saw; monotonic until reset(). Every non-empty frame ends up in exactly
// one of frames, crc_errors, cobs_errors, oversize and runts.
struct DeframerCounters {
  std::uint64_t frames = 0;  // payloads delivered
  // Line bytes of every frame not delivered, its delimiter included. Bytes of delivered frames
  // and the delimiters of empty frames are not counted, so bytes fed == line bytes of delivered
  // frames (delimiters included) + discarded_bytes + empty frames + pending_bytes().
  std::uint64_t discarded_bytes = 0;
  std::uint64_t crc_errors = 0;   // decoded fine, checksum wrong (noise, or frames merged by a cut)
  std::uint64_t cobs_errors = 0;  // a code byte announced more data than the frame had
  std::uint64_t oversize = 0;     // longer than max_payload allows; skipped, never buffered
  std::uint64_t runts = 0;        // decoded to fewer bytes than the CRC alone

  DeframerCounters& operator+=(const DeframerCounters& o) {
    frames += o.frames;
    discarded_bytes += o.discarded_bytes;
    crc_errors += o.crc_errors;
    cobs_errors += o.cobs_errors;
    oversize += o.oversize;
    runts += o.runts;
    return *this;
  }
};

// Splits a serial byte stream, fed in chunks split anywhere, into the payloads of intact frames.
// A frame that fails any check is dropped and counted, and decoding resumes after the next
// delimiter: the deframer never gives up on a stream. Frames are decoded as their bytes arrive
// into one reused buffer, so memory stays bounded by max_payload and steady-state operation
// does not allocate. Empty frames (two delimiters in a row) are skipped silently: senders use
// them to flush a receiver.
class SerialDeframer {
 public:
  // Frames whose payload would exceed `max_payload` (capped at kMaxSerialPayload) are oversize.
  explicit SerialDeframer(std::size_t max_payload);

  // Consumes bytes from the front of `input` until a payload is complete and returns it, or
  // returns nullopt once `input` is exhausted. The payload view stays valid until the next call
  // of next(), feed() or reset(). Lets a caller stop mid-chunk (e.g. when its queue is full) and
  // resume later with the rest of `input`.
  std::optional<std::span<const std::uint8_t>> next(std::span<const std::uint8_t>& input);

  // Consumes all of `input`, calling on_payload(std::span<const std::uint8_t>) for each payload;
  // the span is valid only during that call.
  template <class OnPayload>
  void feed(std::span<const std::uint8_t> input, OnPayload&& on_payload) {
    while (auto payload = next(input)) on_payload(*payload);
  }

  const DeframerCounters& counters() const noexcept { return counters_; }
  std::size_t max_payload() const noexcept { return max_payload_; }
  // Bytes of the frame in progress consumed so far (0 at a frame boundary).
  std::size_t pending_bytes() const noexcept { return frame_bytes_; }
  // Memory held for decoding, which never exceeds what a max_payload frame needs.
  std::size_t buffer_capacity() const noexcept { return decoded_.capacity(); }

  // Back to the state after construction: drops a partial frame without counting it and zeroes
  // the counters. (To drop a partial frame but count it, feed a kFrameDelimiter instead.)
  void reset();

 private:
  void start_frame();
  std::optional<std::span<const std::uint8_t>> end_frame();
  void reject(std::uint64_t& counter);

  std::size_t max_payload_;
  std::size_t max_decoded_;  // max_payload_ + CRC
  std::size_t max_encoded_;  // longest line encoding of max_decoded_ bytes, delimiter excluded
  DeframerCounters counters_;
  std::vector<std::uint8_t> decoded_;  // the frame decoded so far (payload + CRC)
  std::size_t frame_bytes_ = 0;        // line bytes of the current frame consumed so far
  std::size_t block_remaining_ = 0;    // data bytes still due in the current COBS block
  std::uint8_t block_code_ = 0;        // code byte of the current COBS block
  bool oversize_ = false;              // skipping the rest of an oversize frame
};

}  // namespace canbridge::backbone
