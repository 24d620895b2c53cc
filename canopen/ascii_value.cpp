#include "canopen/ascii_value.hpp"

#include <array>
#include <charconv>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

#include "canopen/little_endian.hpp"

namespace canbridge::canopen {

namespace {

struct TypeInfo {
  AsciiType type;
  std::string_view name;
  std::size_t size;
};

constexpr std::array<TypeInfo, 20> kTypes{{
    {AsciiType::b, "b", 1},     {AsciiType::u8, "u8", 1},   {AsciiType::u16, "u16", 2},
    {AsciiType::u32, "u32", 4}, {AsciiType::u64, "u64", 8}, {AsciiType::i8, "i8", 1},
    {AsciiType::i16, "i16", 2}, {AsciiType::i32, "i32", 4}, {AsciiType::i64, "i64", 8},
    {AsciiType::x8, "x8", 1},   {AsciiType::x16, "x16", 2}, {AsciiType::x32, "x32", 4},
    {AsciiType::x64, "x64", 8}, {AsciiType::r32, "r32", 4}, {AsciiType::r64, "r64", 8},
    {AsciiType::vs, "vs", 0},   {AsciiType::os, "os", 0},   {AsciiType::us, "us", 0},
    {AsciiType::d, "d", 0},     {AsciiType::hex, "hex", 0},
}};

const TypeInfo& info(AsciiType type) {
  return kTypes[static_cast<std::size_t>(type)];
}

bool is_space(char c) {
  return c == ' ' || c == '\t';
}

std::string_view trim(std::string_view text) {
  while (!text.empty() && is_space(text.front())) text.remove_prefix(1);
  while (!text.empty() && is_space(text.back())) text.remove_suffix(1);
  return text;
}

AsciiValue fail(std::string error) {
  return AsciiValue{{}, std::move(error)};
}

AsciiValue little_endian(std::uint64_t value, std::size_t size) {
  AsciiValue out;
  out.bytes.resize(size);
  store_le(value, out.bytes);
  return out;
}

// A single token: no spaces inside (numbers and base64 take one).
bool single_token(std::string_view text) {
  for (char c : text) {
    if (is_space(c)) return false;
  }
  return true;
}

AsciiValue parse_unsigned_value(AsciiType type, std::string_view text) {
  const std::size_t size = info(type).size;
  const std::uint64_t max =
      size == 8 ? std::numeric_limits<std::uint64_t>::max() : (std::uint64_t{1} << (8 * size)) - 1;
  if (!text.empty() && (text.front() == '-' || text.front() == '+')) {
    return fail("value " + ascii_excerpt(text) + ": no sign allowed for " +
                std::string(info(type).name));
  }
  const auto value = parse_ascii_unsigned(text, std::numeric_limits<std::uint64_t>::max());
  if (!value) return fail("value " + ascii_excerpt(text) + ": not a number");
  if (*value > max) {
    return fail("value " + ascii_excerpt(text) + " out of range for " +
                std::string(info(type).name));
  }
  return little_endian(*value, size);
}

AsciiValue parse_signed_value(AsciiType type, std::string_view text) {
  const std::size_t size = info(type).size;
  bool negative = false;
  std::string_view digits = text;
  if (!digits.empty() && (digits.front() == '-' || digits.front() == '+')) {
    negative = digits.front() == '-';
    digits.remove_prefix(1);
  }
  if (!digits.empty() && (digits.front() == '-' || digits.front() == '+')) {
    return fail("value " + ascii_excerpt(text) + ": not a number");
  }
  const auto magnitude = parse_ascii_unsigned(digits, std::numeric_limits<std::uint64_t>::max());
  if (!magnitude) return fail("value " + ascii_excerpt(text) + ": not a number");
  const std::uint64_t max_positive = (std::uint64_t{1} << (8 * size - 1)) - 1;
  const std::uint64_t limit = negative ? max_positive + 1 : max_positive;
  if (*magnitude > limit) {
    return fail("value " + ascii_excerpt(text) + " out of range for " +
                std::string(info(type).name));
  }
  // Two's complement of the magnitude; the store keeps the type's low bytes.
  const std::uint64_t bits = negative ? ~*magnitude + 1 : *magnitude;
  return little_endian(bits, size);
}

AsciiValue parse_real_value(AsciiType type, std::string_view text) {
  double value = 0;
  const char* first = text.data();
  const char* last = text.data() + text.size();
  if (first != last && *first == '+') ++first;  // strtod takes a plus sign; from_chars does not
  const auto [end, ec] = std::from_chars(first, last, value);
  if (ec == std::errc::result_out_of_range) {
    return fail("value " + ascii_excerpt(text) + " out of range for " +
                std::string(info(type).name));
  }
  if (ec != std::errc() || end != last || first == last) {
    return fail("value " + ascii_excerpt(text) + ": not a number");
  }
  if (type == AsciiType::r32) {
    const auto narrow = static_cast<float>(value);
    if (std::isinf(narrow) && !std::isinf(value)) {
      return fail("value " + ascii_excerpt(text) + " out of range for r32");
    }
    std::uint32_t bits = 0;
    std::memcpy(&bits, &narrow, sizeof bits);
    return little_endian(bits, 4);
  }
  std::uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  return little_endian(bits, 8);
}

// One word, or a string in double quotes in which a doubled quote stands for one.
AsciiValue parse_visible_string(std::string_view text) {
  AsciiValue out;
  if (text.front() != '"') {
    for (char c : text) {
      if (is_space(c))
        return fail("string " + ascii_excerpt(text) + ": more than one word unquoted");
      if (c == '"')
        return fail("string " + ascii_excerpt(text) + ": quote inside an unquoted word");
      out.bytes.push_back(static_cast<std::uint8_t>(c));
    }
    return out;
  }
  std::size_t i = 1;
  for (;; ++i) {
    if (i >= text.size()) return fail("string " + ascii_excerpt(text) + ": no closing quote");
    if (text[i] == '"') {
      if (i + 1 < text.size() && text[i + 1] == '"') {
        out.bytes.push_back('"');
        ++i;
        continue;
      }
      break;
    }
    out.bytes.push_back(static_cast<std::uint8_t>(text[i]));
  }
  if (i + 1 != text.size())
    return fail("string " + ascii_excerpt(text) + ": text after the closing quote");
  return out;
}

int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

// Pairs of hex digits; a space ends a byte early ("1 02" is 01 02), as CANopenNode reads it.
AsciiValue parse_hex(std::string_view text) {
  AsciiValue out;
  int pending = -1;
  for (char c : text) {
    const int digit = hex_digit(c);
    if (digit >= 0) {
      if (pending < 0) {
        pending = digit;
      } else {
        out.bytes.push_back(static_cast<std::uint8_t>(pending * 16 + digit));
        pending = -1;
      }
    } else if (is_space(c)) {
      if (pending >= 0) out.bytes.push_back(static_cast<std::uint8_t>(pending));
      pending = -1;
    } else {
      return fail("hex " + ascii_excerpt(text) + ": " + ascii_excerpt(std::string_view(&c, 1)) +
                  " is not a hex digit");
    }
  }
  if (pending >= 0) out.bytes.push_back(static_cast<std::uint8_t>(pending));
  return out;
}

constexpr char kBase64[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

int base64_digit(char c) {
  if (c >= 'A' && c <= 'Z') return c - 'A';
  if (c >= 'a' && c <= 'z') return c - 'a' + 26;
  if (c >= '0' && c <= '9') return c - '0' + 52;
  if (c == '+') return 62;
  if (c == '/') return 63;
  return -1;
}

}  // namespace

std::optional<AsciiType> parse_ascii_type(std::string_view token) {
  for (const auto& t : kTypes) {
    if (t.name == token) return t.type;
  }
  return std::nullopt;
}

std::string_view ascii_type_name(AsciiType type) {
  return info(type).name;
}

std::size_t ascii_type_size(AsciiType type) {
  return info(type).size;
}

std::optional<std::uint64_t> parse_ascii_unsigned(std::string_view token, std::uint64_t max) {
  if (token.empty()) return std::nullopt;
  int base = 10;
  if (token.size() > 2 && token[0] == '0' && (token[1] == 'x' || token[1] == 'X')) {
    base = 16;
    token.remove_prefix(2);
  } else if (token.size() > 1 && token[0] == '0') {
    base = 8;
    token.remove_prefix(1);
  }
  std::uint64_t value = 0;
  const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value, base);
  if (ec != std::errc() || end != token.data() + token.size() || value > max) return std::nullopt;
  return value;
}

AsciiValue parse_ascii_value(AsciiType type, std::string_view text) {
  text = trim(text);
  if (text.empty()) return fail(std::string("missing value for ") + std::string(info(type).name));
  switch (type) {
    case AsciiType::vs:
      return parse_visible_string(text);
    case AsciiType::hex:
      return parse_hex(text);
    default:
      break;
  }
  if (!single_token(text)) return fail("value " + ascii_excerpt(text) + ": more than one token");
  switch (type) {
    case AsciiType::b:
    case AsciiType::u8:
    case AsciiType::u16:
    case AsciiType::u32:
    case AsciiType::u64:
    case AsciiType::x8:
    case AsciiType::x16:
    case AsciiType::x32:
    case AsciiType::x64:
      return parse_unsigned_value(type, text);
    case AsciiType::i8:
    case AsciiType::i16:
    case AsciiType::i32:
    case AsciiType::i64:
      return parse_signed_value(type, text);
    case AsciiType::r32:
    case AsciiType::r64:
      return parse_real_value(type, text);
    case AsciiType::os:
    case AsciiType::us:
    case AsciiType::d: {
      auto bytes = base64_decode(text);
      if (!bytes) return fail("value " + ascii_excerpt(text) + ": not base64 (RFC 2045)");
      return AsciiValue{std::move(*bytes), {}};
    }
    case AsciiType::vs:
    case AsciiType::hex:
      break;
  }
  return fail("unsupported datatype");
}

std::string format_ascii_value(AsciiType type, std::span<const std::uint8_t> bytes) {
  const std::size_t size = info(type).size;
  if (size != 0 && bytes.size() != size) type = AsciiType::hex;
  const std::uint64_t raw = load_le(bytes);
  char buf[40];
  switch (type) {
    case AsciiType::b:
    case AsciiType::u8:
    case AsciiType::u16:
    case AsciiType::u32:
    case AsciiType::u64:
      std::snprintf(buf, sizeof buf, "%" PRIu64, raw);
      return buf;
    case AsciiType::i8:
    case AsciiType::i16:
    case AsciiType::i32:
    case AsciiType::i64: {
      // Sign-extend from the type's width.
      const unsigned shift = static_cast<unsigned>(64 - 8 * size);
      const auto value = static_cast<std::int64_t>(raw << shift) >> shift;
      std::snprintf(buf, sizeof buf, "%" PRId64, value);
      return buf;
    }
    case AsciiType::x8:
    case AsciiType::x16:
    case AsciiType::x32:
    case AsciiType::x64:
      std::snprintf(buf, sizeof buf, "0x%0*" PRIX64, static_cast<int>(2 * size), raw);
      return buf;
    case AsciiType::r32: {
      float value = 0;
      const auto bits = static_cast<std::uint32_t>(raw);
      std::memcpy(&value, &bits, sizeof value);
      std::snprintf(buf, sizeof buf, "%g", static_cast<double>(value));
      return buf;
    }
    case AsciiType::r64: {
      double value = 0;
      std::memcpy(&value, &raw, sizeof value);
      std::snprintf(buf, sizeof buf, "%g", value);
      return buf;
    }
    case AsciiType::vs: {
      // NUL and CR are left out (a string padded with NULs prints as its text).
      std::string out = "\"";
      for (std::uint8_t c : bytes) {
        if (c == 0 || c == '\r') continue;
        out += static_cast<char>(c);
        if (c == '"') out += '"';
      }
      return out + "\"";
    }
    case AsciiType::os:
    case AsciiType::us:
    case AsciiType::d:
      return base64_encode(bytes);
    case AsciiType::hex: {
      std::string out;
      out.reserve(bytes.size() * 3);
      for (std::uint8_t c : bytes) {
        if (!out.empty()) out += ' ';
        std::snprintf(buf, sizeof buf, "%02X", c);
        out += buf;
      }
      return out;
    }
  }
  return {};
}

std::string base64_encode(std::span<const std::uint8_t> bytes) {
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 3 <= bytes.size(); i += 3) {
    const std::uint32_t word = (bytes[i] << 16) | (bytes[i + 1] << 8) | bytes[i + 2];
    out += kBase64[(word >> 18) & 0x3F];
    out += kBase64[(word >> 12) & 0x3F];
    out += kBase64[(word >> 6) & 0x3F];
    out += kBase64[word & 0x3F];
  }
  const std::size_t rest = bytes.size() - i;
  if (rest == 1) {
    const std::uint32_t word = bytes[i] << 16;
    out += kBase64[(word >> 18) & 0x3F];
    out += kBase64[(word >> 12) & 0x3F];
    out += "==";
  } else if (rest == 2) {
    const std::uint32_t word = (bytes[i] << 16) | (bytes[i + 1] << 8);
    out += kBase64[(word >> 18) & 0x3F];
    out += kBase64[(word >> 12) & 0x3F];
    out += kBase64[(word >> 6) & 0x3F];
    out += '=';
  }
  return out;
}

std::optional<std::vector<std::uint8_t>> base64_decode(std::string_view text) {
  std::size_t padding = 0;
  while (!text.empty() && text.back() == '=' && padding < 2) {
    text.remove_suffix(1);
    ++padding;
  }
  // Padded text comes in whole groups of four; unpadded text may end after 2 or 3 digits.
  if (padding > 0 && (text.size() + padding) % 4 != 0) return std::nullopt;
  if (text.size() % 4 == 1) return std::nullopt;
  std::vector<std::uint8_t> out;
  out.reserve(text.size() * 3 / 4);
  std::uint32_t word = 0;
  int digits = 0;
  for (char c : text) {
    const int digit = base64_digit(c);
    if (digit < 0) return std::nullopt;
    word = (word << 6) | static_cast<std::uint32_t>(digit);
    if (++digits == 4) {
      out.push_back(static_cast<std::uint8_t>(word >> 16));
      out.push_back(static_cast<std::uint8_t>(word >> 8));
      out.push_back(static_cast<std::uint8_t>(word));
      word = 0;
      digits = 0;
    }
  }
  if (digits == 2) {
    out.push_back(static_cast<std::uint8_t>(word >> 4));
  } else if (digits == 3) {
    out.push_back(static_cast<std::uint8_t>(word >> 10));
    out.push_back(static_cast<std::uint8_t>(word >> 2));
  }
  return out;
}

std::string ascii_excerpt(std::string_view text) {
  std::string out = "\"";
  for (std::size_t i = 0; i < text.size() && i < 32; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7F && c != '"') {
      out += static_cast<char>(c);
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02X", c);
      out += buf;
    }
  }
  if (text.size() > 32) out += "...";
  return out + "\"";
}

}  // namespace canbridge::canopen
