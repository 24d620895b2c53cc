// Frames opaque messages on a byte stream as varint length + bytes (protobuf's delimited format),
// and splits a stream received in arbitrary chunks back into messages. Pure: no I/O.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <system_error>
#include <type_traits>
#include <vector>

namespace google::protobuf {
class MessageLite;
}

namespace canbridge::backbone {

// Why a backbone stream or link ended (the first two poison a DelimitedDecoder).
enum class errc {
  malformed_length = 1,  // length prefix longer than 5 bytes or wider than 32 bits
  message_too_large,     // announced length exceeds the configured maximum
  peer_closed,           // the peer closed the connection (EOF)
  closed,                // closed locally (close() / stop())
  handler_failed,        // a user handler or source threw; the link was dropped
  refused_by_peer,       // the peer refused this side (session Refusal): retrying soon is futile
};

const std::error_category& backbone_category() noexcept;
std::error_code make_error_code(errc e) noexcept;

inline constexpr std::size_t kDefaultMaxMessageSize = std::size_t{1} << 20;  // 1 MiB
inline constexpr std::size_t kMaxLengthPrefixBytes = 5;  // a varint32 never needs more

// Bytes the varint encoding of `value` occupies (1..5 for a length prefix, up to 10 for the
// 64-bit fields of an envelope written by hand, see envelope_codec.hpp).
std::size_t varint_size(std::uint64_t value) noexcept;

// Writes the varint encoding of `value` at `p`, which must have room for varint_size(value)
// bytes; returns the byte after it.
std::uint8_t* write_varint(std::uint64_t value, std::uint8_t* p) noexcept;

// Appends the length prefix and then `message` to `out`.
void append_delimited(std::string& out, std::span<const std::uint8_t> message);

// Appends `message` in delimited form, serialized directly into `out` (no temporary string).
// Throws std::length_error for a message above 2 GiB, which protobuf cannot serialize anyway.
void append_message(std::string& out, const google::protobuf::MessageLite& message);

// Incremental splitter for a delimited stream. Feed it chunks split anywhere (even inside a
// length prefix); it yields complete messages in order. A message that lies wholly inside the
// chunk being fed is returned as a view into that chunk (zero copy); only a message that spans
// chunks is assembled in the internal buffer, which therefore never holds more than one partial
// message (<= max_message_size bytes): no consumed bytes linger, nothing needs compacting.
// After an error the decoder stays poisoned: a length-prefixed stream cannot be resynchronised.
class DelimitedDecoder {
 public:
  explicit DelimitedDecoder(std::size_t max_message_size = kDefaultMaxMessageSize);

  // Consumes bytes from the front of `input` until one message is complete and returns it, or
  // returns nullopt once `input` is exhausted (or on error: check error()). The returned view is
  // valid until the next call and until the memory behind `input` changes.
  std::optional<std::span<const std::uint8_t>> next(std::span<const std::uint8_t>& input);

  // Feeds a whole chunk, calling on_message(std::span<const std::uint8_t>) for each message.
  // Returns error() (sticky).
  template <typename OnMessage>
  std::error_code feed(std::span<const std::uint8_t> input, OnMessage&& on_message) {
    while (auto message = next(input)) on_message(*message);
    return error_;
  }

  std::error_code error() const noexcept { return error_; }
  std::size_t max_message_size() const noexcept { return max_message_size_; }
  // True between messages, i.e. when a stream could end here without truncating a message.
  bool at_message_boundary() const noexcept { return !error_ && prefix_bytes_ == 0 && !length_; }

 private:
  void fail(errc e);

  std::size_t max_message_size_;
  std::error_code error_;
  std::uint64_t prefix_value_ = 0;     // length bits gathered so far
  std::size_t prefix_bytes_ = 0;       // prefix bytes consumed for the current message
  std::optional<std::size_t> length_;  // set once the prefix is complete
  std::vector<std::uint8_t> partial_;  // body of a message that spans chunks
  bool release_partial_ = false;       // partial_ was handed out; clear it on the next call
};

}  // namespace canbridge::backbone

template <>
struct std::is_error_code_enum<canbridge::backbone::errc> : std::true_type {};
