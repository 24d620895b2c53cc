// Consistent Overhead Byte Stuffing: re-codes a message without zero bytes, so that a serial
// line can use 0x00 as an unambiguous frame delimiter and a receiver can resynchronise on it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace canbridge::backbone {

// Standard COBS (Cheshire & Baker): a code byte n (1..255) is followed by n - 1 data bytes;
// codes below 0xFF stand for a zero after their data unless they end the message, code 0xFF
// (254 data bytes) for none. An encoding never contains 0x00 and carries no delimiter itself.
// A message ending in a full 0xFF block gets no extra 0x01 block (as on Wikipedia); decoding
// accepts both forms.

// An upper bound on the size of any valid encoding of an n-byte message, the form with the
// extra 0x01 block included: one code byte per 254 bytes plus one. Exact (n + 1) for n < 254.
constexpr std::size_t cobs_max_encoded_size(std::size_t n) noexcept {
  return n + n / 254 + 1;
}

// Appends the encoding of `in` to `out` (an empty message encodes as the single byte 0x01).
void cobs_encode(std::span<const std::uint8_t> in, std::string& out);

// Encodes one message that is handed over in pieces (e.g. a payload, then its checksum), so the
// pieces never have to be copied next to each other first.
class CobsEncoder {
 public:
  // Starts a message whose encoding is appended to `out`; `out` must outlive this encoder and
  // must not be changed by anyone else until finish().
  explicit CobsEncoder(std::string& out);

  void add(std::span<const std::uint8_t> bytes);
  // Ends the message; the encoder must not be used afterwards.
  void finish();

 private:
  void open_block();
  void close_block();

  std::string& out_;
  std::size_t code_position_ = 0;  // where the current block's code byte goes in out_
  std::uint8_t code_ = 1;          // the current block's code: its data bytes so far + 1
  bool block_open_ = false;        // false right after a full 0xFF block closed
};

// Appends the message encoded in `in` to `out`. Returns false, leaving `out` as it was, when `in`
// is not a valid encoding: empty, containing a zero byte, or a code byte announcing more data
// bytes than follow.
[[nodiscard]] bool cobs_decode(std::span<const std::uint8_t> in, std::vector<std::uint8_t>& out);

}  // namespace canbridge::backbone
