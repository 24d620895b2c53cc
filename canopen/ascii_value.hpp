// Object values as CiA 309-3 text (the datatypes of CANopenNode's ASCII gateway): parsing a
// command's value into the little-endian bytes an SDO download carries, and printing an upload's
// bytes back, so that the command endpoint and its clients agree on every format.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace canbridge::canopen {

enum class AsciiType : std::uint8_t {
  b,
  u8,
  u16,
  u32,
  u64,
  i8,
  i16,
  i32,
  i64,
  x8,
  x16,
  x32,
  x64,
  r32,
  r64,
  vs,   // visible string: "quoted" (inner quote doubled) or one word
  os,   // octet string: base64
  us,   // unicode string: base64
  d,    // domain: base64
  hex,  // bytes as hex digits, optionally space separated (CANopenNode's extension)
};

// The type named by a datatype token ("u16", "vs", ...); nullopt for anything else.
std::optional<AsciiType> parse_ascii_type(std::string_view token);
std::string_view ascii_type_name(AsciiType type);
// The byte size of fixed-size types; 0 for vs, os, us, d and hex.
std::size_t ascii_type_size(AsciiType type);

// A parsed value or why it is not one (for the operator: "value 300 out of range for u8").
struct AsciiValue {
  std::vector<std::uint8_t> bytes;
  std::string error;  // empty: `bytes` holds the value
  bool ok() const { return error.empty(); }
};

// `text` is everything after the datatype on the command line, comment already removed.
// Integers take C's forms (decimal, 0x hex, leading-0 octal; a sign only for signed types) and
// must fit the type; vs takes one word or a quoted string; os/us/d one base64 token; hex takes
// pairs of hex digits with optional spaces between bytes. Anything left over is an error.
AsciiValue parse_ascii_value(AsciiType type, std::string_view text);

// The text CANopenNode's gateway prints for an uploaded value. A fixed-size type whose byte count
// does not match (the node answered with another size) falls back to hex, as CANopenNode does.
std::string format_ascii_value(AsciiType type, std::span<const std::uint8_t> bytes);

// RFC 2045 base64 on one line, with padding.
std::string base64_encode(std::span<const std::uint8_t> bytes);
// Strict: only the base64 alphabet, padding only at the end; nullopt for anything else.
std::optional<std::vector<std::uint8_t>> base64_decode(std::string_view text);

// An unsigned number as C's strtoul(…, 0) reads it (decimal, 0x hex, leading-0 octal), but the
// whole token must be the number and no sign is allowed; nullopt when it is not or exceeds `max`.
std::optional<std::uint64_t> parse_ascii_unsigned(std::string_view token, std::uint64_t max);

// A token quoted for an error message: at most 32 characters, other bytes as \xNN.
std::string ascii_excerpt(std::string_view text);

}  // namespace canbridge::canopen
