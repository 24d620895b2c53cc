#include "backbone/serial_framing.hpp"

#include <algorithm>
#include <array>

#include "backbone/crc32c.hpp"
#include "backbone/little_endian.hpp"

namespace canbridge::backbone {

namespace {

constexpr std::uint8_t kCobsFullBlockCode = 0xFF;  // COBS: 254 data bytes and no implied zero

}  // namespace

void append_serial_frame(std::string& out, std::span<const std::uint8_t> payload) {
  const std::uint32_t crc = crc32c(payload);
  const std::array<std::uint8_t, kFrameCrcSize> crc_bytes{
      static_cast<std::uint8_t>(crc), static_cast<std::uint8_t>(crc >> 8),
      static_cast<std::uint8_t>(crc >> 16), static_cast<std::uint8_t>(crc >> 24)};
  out.reserve(out.size() + serial_frame_max_size(payload.size()));
  CobsEncoder encoder(out);
  encoder.add(payload);
  encoder.add(crc_bytes);
  encoder.finish();
  out.push_back(static_cast<char>(kFrameDelimiter));
}

SerialDeframer::SerialDeframer(std::size_t max_payload)
    : max_payload_(std::min(max_payload, kMaxSerialPayload)),
      max_decoded_(max_payload_ + kFrameCrcSize),
      max_encoded_(cobs_max_encoded_size(max_decoded_)) {}

void SerialDeframer::reset() {
  counters_ = {};
  decoded_.clear();
  start_frame();
}

void SerialDeframer::start_frame() {
  frame_bytes_ = 0;
  block_remaining_ = 0;
  block_code_ = 0;
  oversize_ = false;
}

void SerialDeframer::reject(std::uint64_t& counter) {
  ++counter;
  counters_.discarded_bytes += frame_bytes_ + 1;  // + the delimiter
  decoded_.clear();
  start_frame();
}

std::optional<std::span<const std::uint8_t>> SerialDeframer::next(
    std::span<const std::uint8_t>& input) {
  while (!input.empty()) {
    if (oversize_) {
      // Skip to the delimiter without keeping anything: memory stays bounded however long the
      // run (a babbling or misconfigured sender, or line noise without zero bytes).
      const auto delimiter = std::find(input.begin(), input.end(), kFrameDelimiter);
      const auto skipped = static_cast<std::size_t>(delimiter - input.begin());
      frame_bytes_ += skipped;
      input = input.subspan(skipped);
      if (input.empty()) break;
      input = input.subspan(1);
      reject(counters_.oversize);
      continue;
    }

    if (input.front() == kFrameDelimiter) {
      input = input.subspan(1);
      if (auto payload = end_frame()) return payload;
      continue;
    }

    if (block_remaining_ == 0) {
      // A code byte. The previous frame's payload may still be in use until this point.
      if (frame_bytes_ == 0) decoded_.clear();
      const bool zero_between_blocks = frame_bytes_ != 0 && block_code_ != kCobsFullBlockCode;
      if (decoded_.size() + (zero_between_blocks ? 1 : 0) > max_decoded_ ||
          frame_bytes_ + 1 > max_encoded_) {
        oversize_ = true;
        continue;
      }
      if (zero_between_blocks) decoded_.push_back(0);
      block_code_ = input.front();
      block_remaining_ = block_code_ - 1u;
      ++frame_bytes_;
      input = input.subspan(1);
      continue;
    }

    // Data bytes of the current block: copy the run up to the block's end or a delimiter.
    const auto window = input.first(std::min(block_remaining_, input.size()));
    const auto run = static_cast<std::size_t>(
        std::find(window.begin(), window.end(), kFrameDelimiter) - window.begin());
    if (decoded_.size() + run > max_decoded_ || frame_bytes_ + run > max_encoded_) {
      oversize_ = true;
      continue;
    }
    decoded_.insert(decoded_.end(), window.begin(),
                    window.begin() + static_cast<std::ptrdiff_t>(run));
    block_remaining_ -= run;
    frame_bytes_ += run;
    input = input.subspan(run);
  }
  return std::nullopt;
}

std::optional<std::span<const std::uint8_t>> SerialDeframer::end_frame() {
  if (frame_bytes_ == 0) return std::nullopt;  // empty frame: a sender's flush, not an error
  if (block_remaining_ != 0) {
    reject(counters_.cobs_errors);
    return std::nullopt;
  }
  if (decoded_.size() < kFrameCrcSize) {
    reject(counters_.runts);
    return std::nullopt;
  }
  const std::size_t payload_size = decoded_.size() - kFrameCrcSize;
  const std::span<const std::uint8_t> payload(decoded_.data(), payload_size);
  if (crc32c(payload) != load_le32(decoded_.data() + payload_size)) {
    reject(counters_.crc_errors);
    return std::nullopt;
  }
  ++counters_.frames;
  start_frame();  // decoded_ is cleared when the next frame starts: the caller reads it now
  return payload;
}

}  // namespace canbridge::backbone
