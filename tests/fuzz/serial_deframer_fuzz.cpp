// libFuzzer target: SerialDeframer on arbitrary line bytes, fed in chunks the input chooses.
//
// Input: byte 0 picks max_payload (0..1275), byte 1 the feeding (low 4 bits: how many chunk-size
// bytes follow, 0 = one chunk; bit 4: pull with next() instead of feed()), then those chunk-size
// bytes (each chunk is 1..256 bytes, cycling), then the line bytes.
//
// Invariants: every payload comes from line bytes that are exactly its frame (payload and CRC);
// the chunking never changes what is delivered or counted; every payload fits max_payload and,
// framed again, deframes to itself; the counters account for every frame and every byte; the
// decode buffer stays bounded.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "backbone/cobs.hpp"
#include "backbone/crc32c.hpp"
#include "backbone/serial_framing.hpp"
#include "tests/fuzz/envelope_pipeline.hpp"

namespace {

using canbridge::backbone::append_serial_frame;
using canbridge::backbone::cobs_decode;
using canbridge::backbone::crc32c;
using canbridge::backbone::DeframerCounters;
using canbridge::backbone::kFrameCrcSize;
using canbridge::backbone::kFrameDelimiter;
using canbridge::backbone::SerialDeframer;
using canbridge::fuzz::require;
using Payloads = std::vector<std::vector<std::uint8_t>>;

bool same_counters(const DeframerCounters& a, const DeframerCounters& b) {
  return a.frames == b.frames && a.discarded_bytes == b.discarded_bytes &&
         a.crc_errors == b.crc_errors && a.cobs_errors == b.cobs_errors &&
         a.oversize == b.oversize && a.runts == b.runts;
}

void keep(Payloads& payloads, const SerialDeframer& deframer,
          std::span<const std::uint8_t> payload) {
  require(payload.size() <= deframer.max_payload(), "payload above max_payload delivered");
  payloads.emplace_back(payload.begin(), payload.end());
}

// True when `frame_bytes` (delimiter included) decodes, by the standalone COBS decoder, to
// `payload` followed by its CRC-32C: checks the deframer's decoding and CRC check independently.
bool is_frame_of(std::span<const std::uint8_t> frame_bytes,
                 const std::vector<std::uint8_t>& payload) {
  std::vector<std::uint8_t> expected = payload;
  const std::uint32_t crc = crc32c(payload);
  for (int shift = 0; shift < 32; shift += 8) expected.push_back((crc >> shift) & 0xFF);
  std::vector<std::uint8_t> decoded;
  return !frame_bytes.empty() && cobs_decode(frame_bytes.first(frame_bytes.size() - 1), decoded) &&
         decoded == expected;
}

void check_reframes(const std::vector<std::uint8_t>& payload, std::size_t max_payload) {
  std::string line;
  append_serial_frame(line, payload);
  SerialDeframer deframer(max_payload);
  Payloads again;
  deframer.feed({reinterpret_cast<const std::uint8_t*>(line.data()), line.size()},
                [&](std::span<const std::uint8_t> p) { keep(again, deframer, p); });
  require(again.size() == 1 && again.front() == payload, "a delivered payload does not re-frame");
  require(deframer.counters().frames == 1 && deframer.counters().discarded_bytes == 0,
          "re-framed payload counted as an error");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const std::size_t max_payload = std::size_t{data[0]} * 5;
  const std::size_t plan_size = data[1] & 0x0F;
  const bool pull = (data[1] & 0x10) != 0;
  if (size < 2 + plan_size) return 0;
  const std::span<const std::uint8_t> plan(data + 2, plan_size);
  const std::span<const std::uint8_t> line(data + 2 + plan_size, size - 2 - plan_size);

  // Reference: the whole line, pulled payload by payload so that each one can be traced back to
  // the exact line bytes it came from.
  SerialDeframer whole(max_payload);
  Payloads expected;
  std::uint64_t delivered_line_bytes = 0;
  std::span<const std::uint8_t> input = line;
  while (auto payload = whole.next(input)) {
    keep(expected, whole, *payload);
    const std::size_t end = line.size() - input.size();  // just past the frame's delimiter
    require(end > 0 && line[end - 1] == kFrameDelimiter, "payload delivered before a delimiter");
    std::size_t start = end - 1;
    while (start > 0 && line[start - 1] != kFrameDelimiter) --start;
    const auto frame_bytes = line.subspan(start, end - start);
    require(is_frame_of(frame_bytes, expected.back()), "payload delivered from a corrupted frame");
    delivered_line_bytes += frame_bytes.size();
  }
  require(input.empty(), "next() returned nullopt before consuming its input");

  SerialDeframer chunked(max_payload);
  Payloads delivered;
  std::span<const std::uint8_t> rest = line;
  for (std::size_t i = 0; !rest.empty(); ++i) {
    const std::size_t chunk_size = plan.empty() ? rest.size() : plan[i % plan.size()] + 1u;
    std::span<const std::uint8_t> chunk = rest.first(std::min(chunk_size, rest.size()));
    rest = rest.subspan(chunk.size());
    if (pull) {
      // One payload per call, as a consumer that stops when its queue is full would take them.
      while (auto payload = chunked.next(chunk)) keep(delivered, chunked, *payload);
      require(chunk.empty(), "next() returned nullopt before consuming its input");
    } else {
      chunked.feed(chunk, [&](std::span<const std::uint8_t> p) { keep(delivered, chunked, p); });
    }
    require(chunked.buffer_capacity() <= 2 * (max_payload + kFrameCrcSize),
            "decode buffer grew beyond what max_payload needs");
  }
  require(delivered == expected, "chunking changed the payloads delivered");
  const DeframerCounters& c = chunked.counters();
  require(same_counters(c, whole.counters()), "chunking changed the counters");
  require(chunked.pending_bytes() == whole.pending_bytes(), "chunking changed the pending bytes");

  // Every non-empty delimited frame is counted exactly once, and every byte is accounted for.
  std::uint64_t delimiters = 0;
  std::uint64_t empty_frames = 0;
  std::size_t after_last_delimiter = 0;
  for (std::size_t i = 0; i < line.size(); ++i) {
    if (line[i] != kFrameDelimiter) continue;
    ++delimiters;
    if (i == 0 || line[i - 1] == kFrameDelimiter) ++empty_frames;
    after_last_delimiter = i + 1;
  }
  const std::uint64_t bad = c.crc_errors + c.cobs_errors + c.oversize + c.runts;
  require(c.frames == delivered.size(), "frames counter differs from the payloads delivered");
  require(c.frames + bad == delimiters - empty_frames, "a frame was counted twice or not at all");
  require(chunked.pending_bytes() == line.size() - after_last_delimiter,
          "pending bytes are not the bytes after the last delimiter");
  require(delivered_line_bytes + c.discarded_bytes + empty_frames + chunked.pending_bytes() ==
              line.size(),
          "discarded_bytes does not account for the stream");

  for (const auto& payload : delivered) check_reframes(payload, max_payload);
  return 0;
}
