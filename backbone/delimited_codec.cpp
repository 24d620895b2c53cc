#include "backbone/delimited_codec.hpp"

#include <google/protobuf/message_lite.h>

#include <algorithm>
#include <climits>
#include <stdexcept>

namespace canbridge::backbone {

namespace {

class BackboneCategory final : public std::error_category {
 public:
  const char* name() const noexcept override { return "canbridge.backbone"; }
  std::string message(int value) const override {
    switch (static_cast<errc>(value)) {
      case errc::malformed_length:
        return "malformed length prefix";
      case errc::message_too_large:
        return "message exceeds the maximum size";
      case errc::peer_closed:
        return "connection closed by peer";
      case errc::closed:
        return "connection closed locally";
      case errc::handler_failed:
        return "message handler or source threw";
      case errc::refused_by_peer:
        return "refused by the peer";
    }
    return "unknown backbone error";
  }
};

// Grows `out` by `n` bytes and returns where they start.
std::uint8_t* grow(std::string& out, std::size_t n) {
  const std::size_t old_size = out.size();
  out.resize(old_size + n);
  return reinterpret_cast<std::uint8_t*>(out.data() + old_size);
}

std::uint32_t checked_length(std::size_t size) {
  // protobuf refuses messages above INT_MAX; the prefix is a varint32 by definition.
  if (size > static_cast<std::size_t>(INT_MAX)) {
    throw std::length_error("backbone: message too large to frame");
  }
  return static_cast<std::uint32_t>(size);
}

}  // namespace

const std::error_category& backbone_category() noexcept {
  static const BackboneCategory category;
  return category;
}

std::error_code make_error_code(errc e) noexcept {
  return {static_cast<int>(e), backbone_category()};
}

std::size_t varint_size(std::uint64_t value) noexcept {
  std::size_t n = 1;
  while (value >= 0x80) {
    value >>= 7;
    ++n;
  }
  return n;
}

std::uint8_t* write_varint(std::uint64_t value, std::uint8_t* p) noexcept {
  while (value >= 0x80) {
    *p++ = static_cast<std::uint8_t>(value | 0x80);
    value >>= 7;
  }
  *p++ = static_cast<std::uint8_t>(value);
  return p;
}

void append_delimited(std::string& out, std::span<const std::uint8_t> message) {
  const std::uint32_t length = checked_length(message.size());
  std::uint8_t* p = grow(out, varint_size(length) + message.size());
  p = write_varint(length, p);
  std::copy(message.begin(), message.end(), p);
}

void append_message(std::string& out, const google::protobuf::MessageLite& message) {
  // ByteSizeLong() caches nested sizes, which SerializeWithCachedSizesToArray() then relies on.
  const std::uint32_t length = checked_length(message.ByteSizeLong());
  std::uint8_t* p = grow(out, varint_size(length) + length);
  p = write_varint(length, p);
  message.SerializeWithCachedSizesToArray(p);
}

DelimitedDecoder::DelimitedDecoder(std::size_t max_message_size)
    : max_message_size_(std::min<std::size_t>(max_message_size, INT_MAX)) {}

void DelimitedDecoder::fail(errc e) {
  error_ = make_error_code(e);
  partial_.clear();
  partial_.shrink_to_fit();
  length_.reset();
}

std::optional<std::span<const std::uint8_t>> DelimitedDecoder::next(
    std::span<const std::uint8_t>& input) {
  if (release_partial_) {
    partial_.clear();  // capacity is kept: it is bounded by max_message_size_
    release_partial_ = false;
  }
  if (error_) return std::nullopt;

  while (!length_) {
    if (input.empty()) return std::nullopt;
    const std::uint8_t byte = input.front();
    input = input.subspan(1);
    // The fifth byte may only carry the top 4 bits of a 32-bit value and must end the prefix.
    if (prefix_bytes_ == kMaxLengthPrefixBytes - 1 && (byte & 0xF0) != 0) {
      fail(errc::malformed_length);
      return std::nullopt;
    }
    prefix_value_ |= std::uint64_t{byte & 0x7Fu} << (7 * prefix_bytes_);
    ++prefix_bytes_;
    if ((byte & 0x80) == 0) {
      if (prefix_value_ > max_message_size_) {
        fail(errc::message_too_large);
        return std::nullopt;
      }
      length_ = static_cast<std::size_t>(prefix_value_);
    }
  }

  const std::size_t length = *length_;
  std::span<const std::uint8_t> message;
  if (partial_.empty() && input.size() >= length) {
    message = input.first(length);  // the common case: the whole body is in this chunk
    input = input.subspan(length);
  } else {
    const std::size_t take = std::min(length - partial_.size(), input.size());
    partial_.insert(partial_.end(), input.begin(),
                    input.begin() + static_cast<std::ptrdiff_t>(take));
    input = input.subspan(take);
    if (partial_.size() < length) return std::nullopt;
    message = partial_;
    release_partial_ = true;
  }
  length_.reset();
  prefix_value_ = 0;
  prefix_bytes_ = 0;
  return message;
}

}  // namespace canbridge::backbone
