// CiA 309-3 value texts: every datatype both ways, in the formats CANopenNode's gateway uses,
// and bad values refused with a reason.
#include "canopen/ascii_value.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

namespace canbridge::canopen {
namespace {

using Bytes = std::vector<std::uint8_t>;

Bytes parse_ok(AsciiType type, std::string_view text) {
  const auto value = parse_ascii_value(type, text);
  EXPECT_TRUE(value.ok()) << text << ": " << value.error;
  return value.bytes;
}

std::string parse_error(AsciiType type, std::string_view text) {
  const auto value = parse_ascii_value(type, text);
  EXPECT_FALSE(value.ok()) << text << " parsed";
  return value.error;
}

TEST(AsciiValue, TypeNamesRoundTrip) {
  for (const char* name : {"b",   "u8",  "u16", "u32", "u64", "i8", "i16", "i32", "i64", "x8",
                           "x16", "x32", "x64", "r32", "r64", "vs", "os",  "us",  "d",   "hex"}) {
    const auto type = parse_ascii_type(name);
    ASSERT_TRUE(type) << name;
    EXPECT_EQ(ascii_type_name(*type), name);
  }
  EXPECT_FALSE(parse_ascii_type("u24"));
  EXPECT_FALSE(parse_ascii_type(""));
  EXPECT_FALSE(parse_ascii_type("U8"));  // the command parser lowers tokens first
  EXPECT_EQ(ascii_type_size(AsciiType::u32), 4u);
  EXPECT_EQ(ascii_type_size(AsciiType::vs), 0u);
}

TEST(AsciiValue, UnsignedLittleEndianInCsForms) {
  EXPECT_EQ(parse_ok(AsciiType::u16, "4660"), (Bytes{0x34, 0x12}));
  EXPECT_EQ(parse_ok(AsciiType::u16, "0x1234"), (Bytes{0x34, 0x12}));
  EXPECT_EQ(parse_ok(AsciiType::u8, "010"), (Bytes{8}));  // strtoul's octal
  EXPECT_EQ(parse_ok(AsciiType::u32, "0xFFFFFFFF"), (Bytes{0xFF, 0xFF, 0xFF, 0xFF}));
  EXPECT_EQ(parse_ok(AsciiType::u64, "18446744073709551615"), Bytes(8, 0xFF));
  EXPECT_EQ(parse_ok(AsciiType::b, "1"), (Bytes{1}));
  EXPECT_EQ(parse_ok(AsciiType::x16, "0xbeef"), (Bytes{0xEF, 0xBE}));
  EXPECT_EQ(parse_ok(AsciiType::u8, "  7  "), (Bytes{7}));
}

TEST(AsciiValue, UnsignedRefusals) {
  EXPECT_NE(parse_error(AsciiType::u8, "256").find("out of range for u8"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u16, "65536").find("out of range"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u32, "0x100000000").find("out of range"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u64, "18446744073709551616").find("not a number"),
            std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "-1").find("no sign"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "12abc").find("not a number"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "0x").find("not a number"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "09").find("not a number"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "").find("missing value"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u8, "1 2").find("more than one token"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::u32, std::string("1\0", 2)).find("not a number"),
            std::string::npos);
}

TEST(AsciiValue, SignedTwosComplementAndRange) {
  EXPECT_EQ(parse_ok(AsciiType::i8, "-128"), (Bytes{0x80}));
  EXPECT_EQ(parse_ok(AsciiType::i8, "127"), (Bytes{0x7F}));
  EXPECT_EQ(parse_ok(AsciiType::i16, "-2"), (Bytes{0xFE, 0xFF}));
  EXPECT_EQ(parse_ok(AsciiType::i32, "+0x10"), (Bytes{0x10, 0, 0, 0}));
  EXPECT_EQ(parse_ok(AsciiType::i64, "-9223372036854775808"), (Bytes{0, 0, 0, 0, 0, 0, 0, 0x80}));
  EXPECT_NE(parse_error(AsciiType::i8, "128").find("out of range for i8"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::i8, "-129").find("out of range"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::i64, "9223372036854775808").find("out of range"),
            std::string::npos);
  EXPECT_NE(parse_error(AsciiType::i16, "--1").find("not a number"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::i16, "-").find("not a number"), std::string::npos);
}

TEST(AsciiValue, Reals) {
  float f = 0;
  const Bytes r32 = parse_ok(AsciiType::r32, "1.5");
  ASSERT_EQ(r32.size(), 4u);
  std::memcpy(&f, r32.data(), 4);
  EXPECT_EQ(f, 1.5f);
  double d = 0;
  const Bytes r64 = parse_ok(AsciiType::r64, "-2.25e3");
  ASSERT_EQ(r64.size(), 8u);
  std::memcpy(&d, r64.data(), 8);
  EXPECT_EQ(d, -2250.0);
  EXPECT_NE(parse_error(AsciiType::r32, "1e60").find("out of range for r32"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::r64, "1.5x").find("not a number"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::r64, "1,5").find("not a number"), std::string::npos);
}

TEST(AsciiValue, VisibleStrings) {
  EXPECT_EQ(parse_ok(AsciiType::vs, "word"), (Bytes{'w', 'o', 'r', 'd'}));
  EXPECT_EQ(parse_ok(AsciiType::vs, "\"two words\""),
            (Bytes{'t', 'w', 'o', ' ', 'w', 'o', 'r', 'd', 's'}));
  EXPECT_EQ(parse_ok(AsciiType::vs, "\"say \"\"hi\"\"\""),
            (Bytes{'s', 'a', 'y', ' ', '"', 'h', 'i', '"'}));
  EXPECT_EQ(parse_ok(AsciiType::vs, "\"\""), Bytes{});
  EXPECT_NE(parse_error(AsciiType::vs, "two words").find("unquoted"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::vs, "\"open").find("no closing quote"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::vs, "\"a\"b").find("after the closing quote"),
            std::string::npos);
  EXPECT_NE(parse_error(AsciiType::vs, "a\"b").find("quote inside"), std::string::npos);
}

TEST(AsciiValue, HexBytesAsCanopenNodeReadsThem) {
  EXPECT_EQ(parse_ok(AsciiType::hex, "01 02 ff"), (Bytes{0x01, 0x02, 0xFF}));
  EXPECT_EQ(parse_ok(AsciiType::hex, "0102FF"), (Bytes{0x01, 0x02, 0xFF}));
  EXPECT_EQ(parse_ok(AsciiType::hex, "1 2 abc"), (Bytes{0x01, 0x02, 0xAB, 0x0C}));
  EXPECT_NE(parse_error(AsciiType::hex, "01 0g").find("not a hex digit"), std::string::npos);
}

TEST(AsciiValue, Base64Rfc2045) {
  const Bytes data{'h', 'e', 'l', 'l', 'o'};
  EXPECT_EQ(base64_encode(data), "aGVsbG8=");
  EXPECT_EQ(base64_encode(Bytes{0xFF}), "/w==");
  EXPECT_EQ(base64_encode(Bytes{0xFB, 0xFF, 0xBF}), "+/+/");
  EXPECT_EQ(base64_encode(Bytes{}), "");
  EXPECT_EQ(parse_ok(AsciiType::d, "aGVsbG8="), data);
  EXPECT_EQ(parse_ok(AsciiType::os, "aGVsbG8"), data);  // padding may be left out
  EXPECT_EQ(parse_ok(AsciiType::us, "/w=="), (Bytes{0xFF}));
  for (int n = 0; n < 40; ++n) {  // every length mod 3, all byte values
    Bytes bytes;
    for (int i = 0; i < n; ++i) bytes.push_back(static_cast<std::uint8_t>(i * 37 + n));
    EXPECT_EQ(base64_decode(base64_encode(bytes)), bytes) << n;
  }
  EXPECT_NE(parse_error(AsciiType::d, "aGV*bG8=").find("not base64"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::d, "a").find("not base64"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::d, "aGVsbG8==").find("not base64"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::d, "aG=Vs").find("not base64"), std::string::npos);
  EXPECT_NE(parse_error(AsciiType::d, "aGVs bG8=").find("more than one token"), std::string::npos);
}

TEST(AsciiValue, PrintsAsCanopenNode) {
  EXPECT_EQ(format_ascii_value(AsciiType::u16, Bytes{0x34, 0x12}), "4660");
  EXPECT_EQ(format_ascii_value(AsciiType::u64, Bytes(8, 0xFF)), "18446744073709551615");
  EXPECT_EQ(format_ascii_value(AsciiType::b, Bytes{1}), "1");
  EXPECT_EQ(format_ascii_value(AsciiType::i8, Bytes{0x80}), "-128");
  EXPECT_EQ(format_ascii_value(AsciiType::i32, Bytes{0xFE, 0xFF, 0xFF, 0xFF}), "-2");
  EXPECT_EQ(format_ascii_value(AsciiType::x8, Bytes{0x0A}), "0x0A");
  EXPECT_EQ(format_ascii_value(AsciiType::x16, Bytes{0xEF, 0xBE}), "0xBEEF");
  EXPECT_EQ(format_ascii_value(AsciiType::x32, Bytes{1, 0, 0, 0}), "0x00000001");
  EXPECT_EQ(format_ascii_value(AsciiType::x64, Bytes{1, 0, 0, 0, 0, 0, 0, 0x80}),
            "0x8000000000000001");
  EXPECT_EQ(format_ascii_value(AsciiType::r32, parse_ok(AsciiType::r32, "1.5")), "1.5");
  EXPECT_EQ(format_ascii_value(AsciiType::r64, parse_ok(AsciiType::r64, "1e100")), "1e+100");
  EXPECT_EQ(format_ascii_value(AsciiType::vs, Bytes{'a', '"', 'b', 0, '\r'}), "\"a\"\"b\"");
  EXPECT_EQ(format_ascii_value(AsciiType::d, Bytes{'h', 'e', 'l', 'l', 'o'}), "aGVsbG8=");
  EXPECT_EQ(format_ascii_value(AsciiType::hex, Bytes{0x01, 0xAB}), "01 AB");
  EXPECT_EQ(format_ascii_value(AsciiType::hex, Bytes{}), "");
}

TEST(AsciiValue, AnotherSizeThanTheTypeFallsBackToHex) {
  EXPECT_EQ(format_ascii_value(AsciiType::u32, Bytes{0x01, 0x02}), "01 02");
  EXPECT_EQ(format_ascii_value(AsciiType::r64, Bytes{0xFF}), "FF");
}

TEST(AsciiValue, ParseThenPrintIsTheSameText) {
  const std::vector<std::pair<AsciiType, std::string>> cases{
      {AsciiType::u32, "305419896"},  {AsciiType::i16, "-300"},
      {AsciiType::x32, "0x0000ABCD"}, {AsciiType::vs, "\"a \"\"b\"\"\""},
      {AsciiType::os, "AAEC/w=="},    {AsciiType::hex, "00 7F 80"},
  };
  for (const auto& [type, text] : cases) {
    EXPECT_EQ(format_ascii_value(type, parse_ok(type, text)), text);
  }
}

}  // namespace
}  // namespace canbridge::canopen
