#include "backbone/delimited_codec.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <vector>

#include "session.pb.h"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

using testing::bytes;
using testing::to_string;

std::string payload(std::size_t size, std::uint8_t seed = 0) {
  std::string s(size, '\0');
  for (std::size_t i = 0; i < size; ++i) s[i] = static_cast<char>((i * 31 + seed) & 0xFF);
  return s;
}

std::vector<std::string> decode_all(DelimitedDecoder& decoder, const std::string& stream,
                                    std::error_code* error = nullptr) {
  std::vector<std::string> out;
  const std::error_code ec = decoder.feed(
      bytes(stream), [&](std::span<const std::uint8_t> m) { out.push_back(to_string(m)); });
  if (error) *error = ec;
  return out;
}

TEST(DelimitedCodec, RoundTripsBoundarySizes) {
  for (std::size_t size : {std::size_t{0}, std::size_t{1}, std::size_t{127}, std::size_t{128},
                           std::size_t{16383}, std::size_t{16384}, kDefaultMaxMessageSize}) {
    SCOPED_TRACE(size);
    const std::string message = payload(size);
    std::string stream;
    append_delimited(stream, bytes(message));
    ASSERT_EQ(stream.size(), varint_size(static_cast<std::uint32_t>(size)) + size);
    DelimitedDecoder decoder;
    std::error_code ec;
    const auto decoded = decode_all(decoder, stream, &ec);
    EXPECT_FALSE(ec) << ec.message();
    ASSERT_EQ(decoded.size(), 1u);
    EXPECT_EQ(decoded[0], message);
    EXPECT_TRUE(decoder.at_message_boundary());
  }
}

TEST(DelimitedCodec, VarintSizesMatchProtobuf) {
  EXPECT_EQ(varint_size(0), 1u);
  EXPECT_EQ(varint_size(127), 1u);
  EXPECT_EQ(varint_size(128), 2u);
  EXPECT_EQ(varint_size(16383), 2u);
  EXPECT_EQ(varint_size(16384), 3u);
  EXPECT_EQ(varint_size(0xFFFFFFFFu), 5u);
  std::string stream;
  append_delimited(stream, bytes(payload(300)));
  EXPECT_EQ(static_cast<std::uint8_t>(stream[0]), 0xAC);  // 300 = 0b10'0101100
  EXPECT_EQ(static_cast<std::uint8_t>(stream[1]), 0x02);
}

TEST(DelimitedCodec, AppendMessageWritesTheDelimitedSerialization) {
  for (std::size_t size : {std::size_t{0}, std::size_t{1}, std::size_t{126}, std::size_t{16384}}) {
    SCOPED_TRACE(size);
    // A message of the backbone's own (lite) schema with one bytes field of the given size.
    canbridge::v1::AuthStep message;
    message.set_challenge(payload(size, 7));
    std::string stream = "prefix";
    append_message(stream, message);
    const std::string serialized = message.SerializeAsString();
    std::string expected = "prefix";
    append_delimited(expected, bytes(serialized));
    EXPECT_EQ(stream, expected);

    DelimitedDecoder decoder;
    const auto decoded = decode_all(decoder, stream.substr(6));
    ASSERT_EQ(decoded.size(), 1u);
    canbridge::v1::AuthStep parsed;
    ASSERT_TRUE(parsed.ParseFromString(decoded[0]));
    EXPECT_EQ(parsed.challenge(), message.challenge());
  }
}

TEST(DelimitedCodec, EmptyProtobufIsAZeroLengthMessage) {
  std::string stream;
  append_message(stream, canbridge::v1::AuthStep{});
  EXPECT_EQ(stream, std::string(1, '\0'));
  DelimitedDecoder decoder;
  const auto decoded = decode_all(decoder, stream + stream);
  ASSERT_EQ(decoded.size(), 2u);
  EXPECT_TRUE(decoded[0].empty());
}

TEST(DelimitedCodec, MaxSizeIsInclusive) {
  DelimitedDecoder decoder(1000);
  std::string stream;
  append_delimited(stream, bytes(payload(1000)));
  std::error_code ec;
  EXPECT_EQ(decode_all(decoder, stream, &ec).size(), 1u);
  EXPECT_FALSE(ec);

  std::string too_big;
  append_delimited(too_big, bytes(payload(1001)));
  EXPECT_TRUE(decode_all(decoder, too_big, &ec).empty());
  EXPECT_EQ(ec, errc::message_too_large);
}

TEST(DelimitedCodec, OversizeIsDetectedFromThePrefixAlone) {
  DelimitedDecoder decoder;  // 1 MiB
  std::string stream;
  append_delimited(stream, bytes(payload(kDefaultMaxMessageSize + 1)));
  std::error_code ec;
  // Only the length prefix is fed: no need to buffer the body to know it is too large.
  EXPECT_TRUE(decode_all(decoder, stream.substr(0, 3), &ec).empty());
  EXPECT_EQ(ec, errc::message_too_large);
  EXPECT_EQ(decoder.error(), errc::message_too_large);
}

TEST(DelimitedCodec, DecodesAStreamSplitAtEveryByteBoundary) {
  std::vector<std::string> messages;
  std::string stream;
  std::uint8_t seed = 0;
  for (std::size_t size : {0, 1, 127, 128, 300, 0, 5}) {
    messages.push_back(payload(size, seed++));
    append_delimited(stream, bytes(messages.back()));
  }
  for (std::size_t split = 0; split <= stream.size(); ++split) {
    SCOPED_TRACE(split);
    DelimitedDecoder decoder;
    auto decoded = decode_all(decoder, stream.substr(0, split));
    const auto rest = decode_all(decoder, stream.substr(split));
    decoded.insert(decoded.end(), rest.begin(), rest.end());
    ASSERT_EQ(decoded, messages);
    EXPECT_FALSE(decoder.error());
  }
}

TEST(DelimitedCodec, DecodesAStreamFedOneByteAtATime) {
  std::vector<std::string> messages;
  std::string stream;
  for (std::size_t size : {16384, 0, 16383, 200}) {
    messages.push_back(payload(size, static_cast<std::uint8_t>(size)));
    append_delimited(stream, bytes(messages.back()));
  }
  DelimitedDecoder decoder;
  std::vector<std::string> decoded;
  for (char c : stream) {
    const auto part = decode_all(decoder, std::string(1, c));
    decoded.insert(decoded.end(), part.begin(), part.end());
  }
  EXPECT_EQ(decoded, messages);
  EXPECT_TRUE(decoder.at_message_boundary());
}

TEST(DelimitedCodec, MessagesWithinOneChunkAreNotCopied) {
  std::string stream;
  append_delimited(stream, bytes(payload(10)));
  append_delimited(stream, bytes(payload(20)));
  DelimitedDecoder decoder;
  std::span<const std::uint8_t> input = bytes(stream);
  const auto* begin = input.data();
  const auto* end = input.data() + input.size();
  int count = 0;
  while (auto m = decoder.next(input)) {
    EXPECT_GE(m->data(), begin);
    EXPECT_LE(m->data() + m->size(), end);
    ++count;
  }
  EXPECT_EQ(count, 2);
  EXPECT_TRUE(input.empty());
}

TEST(DelimitedCodec, SixByteVarintIsMalformedAndPoisonsTheDecoder) {
  DelimitedDecoder decoder;
  const std::string garbage("\x80\x80\x80\x80\x80\x01", 6);
  std::error_code ec;
  EXPECT_TRUE(decode_all(decoder, garbage, &ec).empty());
  EXPECT_EQ(ec, errc::malformed_length);

  // A valid message afterwards is not delivered: the stream cannot be resynchronised.
  std::string valid;
  append_delimited(valid, bytes(payload(3)));
  EXPECT_TRUE(decode_all(decoder, valid, &ec).empty());
  EXPECT_EQ(ec, errc::malformed_length);
}

TEST(DelimitedCodec, LengthWiderThan32BitsIsMalformed) {
  // No limit at all (the largest size_t; 1 << 40 does not fit a 32-bit size_t): only the
  // prefix's width can make a 33-bit length malformed.
  DelimitedDecoder decoder(std::numeric_limits<std::size_t>::max());
  std::error_code ec;
  EXPECT_TRUE(decode_all(decoder, std::string("\xFF\xFF\xFF\xFF\x10", 5), &ec).empty());
  EXPECT_EQ(ec, errc::malformed_length);
}

TEST(DelimitedCodec, MalformedPrefixSplitAcrossChunksIsDetected) {
  DelimitedDecoder decoder;
  std::error_code ec;
  EXPECT_TRUE(decode_all(decoder, std::string("\xFF\xFF\xFF", 3), &ec).empty());
  EXPECT_FALSE(ec);
  EXPECT_FALSE(decoder.at_message_boundary());
  EXPECT_TRUE(decode_all(decoder, std::string("\xFF\xFF", 2), &ec).empty());
  EXPECT_EQ(ec, errc::malformed_length);
}

TEST(DelimitedCodec, ErrorCategoryNamesTheBackbone) {
  const std::error_code ec = errc::message_too_large;
  EXPECT_STREQ(ec.category().name(), "canbridge.backbone");
  EXPECT_EQ(ec.message(), "message exceeds the maximum size");
  EXPECT_NE(std::error_code(errc::peer_closed), std::error_code(errc::closed));
}

}  // namespace
}  // namespace canbridge::backbone
