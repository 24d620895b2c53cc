// Envelopes written by hand parse as the same v1::Envelope through protobuf, and their length
// prefix is what a DelimitedDecoder needs to split them from a stream.
#include "backbone/envelope_codec.hpp"

#include <gtest/gtest.h>

#include <limits>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "session.pb.h"

namespace canbridge::backbone {
namespace {

constexpr std::uint64_t kHuge = std::numeric_limits<std::uint64_t>::max();

std::span<const std::uint8_t> bytes_of(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

// Splits `stream` into exactly one delimited message and parses it.
v1::Envelope parse_one(const std::string& stream) {
  DelimitedDecoder decoder(std::size_t{64} << 20);
  std::vector<std::string> messages;
  const std::error_code ec = decoder.feed(bytes_of(stream), [&](std::span<const std::uint8_t> m) {
    messages.emplace_back(reinterpret_cast<const char*>(m.data()), m.size());
  });
  EXPECT_FALSE(ec);
  EXPECT_TRUE(decoder.at_message_boundary());  // the prefix covers the envelope exactly
  EXPECT_EQ(messages.size(), 1u);
  v1::Envelope envelope;
  EXPECT_TRUE(!messages.empty() && envelope.ParseFromString(messages.front()));
  return envelope;
}

// What protobuf itself writes for the same envelope. The hand-written one puts the body last (the
// wire has always had that order; protobuf parses fields in any order), so only sizes compare.
std::string by_protobuf(const v1::Envelope& envelope) {
  std::string out;
  append_message(out, envelope);
  return out;
}

void expect_header(const v1::Envelope& e, const EnvelopeHeader& h) {
  EXPECT_EQ(e.seq(), h.seq);
  EXPECT_EQ(e.ack(), h.ack);
  EXPECT_EQ(e.resend(), h.resend);
  EXPECT_EQ(std::vector<std::uint64_t>(e.missing().begin(), e.missing().end()),
            std::vector<std::uint64_t>(h.missing.begin(), h.missing.end()));
  EXPECT_EQ(e.unreliable_seq(), h.unreliable_seq);
}

TEST(EnvelopeCodec, PayloadEnvelopesParseAsWritten) {
  const std::vector<std::uint64_t> holes{7, 9, 300, kHuge};
  const std::vector<EnvelopeHeader> headers{
      {},
      {.seq = 1},
      {.seq = 127, .ack = 128},
      {.seq = kHuge, .ack = kHuge - 1},
      {.ack = 5, .resend = true},
      {.seq = 12, .ack = 5, .resend = true, .missing = holes},
      {.unreliable_seq = 1},
      {.ack = 3, .unreliable_seq = 16384},
  };
  for (std::size_t size : {std::size_t{0}, std::size_t{1}, std::size_t{127}, std::size_t{128},
                           std::size_t{70000}, std::size_t{3} << 20}) {
    std::string payload(size, '\0');
    for (std::size_t i = 0; i < size; ++i) payload[i] = static_cast<char>(i * 13 + 1);
    for (const EnvelopeHeader& h : headers) {
      SCOPED_TRACE(::testing::Message() << "size " << size << " seq " << h.seq << " ack " << h.ack);
      std::string out = "x";  // appends: what was there stays
      append_payload_envelope(out, h, bytes_of(payload));
      ASSERT_EQ(out.front(), 'x');
      const v1::Envelope e = parse_one(out.substr(1));
      expect_header(e, h);
      ASSERT_EQ(e.body_case(), v1::Envelope::kPayload);
      EXPECT_EQ(e.payload(), payload);
      EXPECT_EQ(out.size() - 1, by_protobuf(e).size());
    }
  }
}

TEST(EnvelopeCodec, KeepaliveEnvelopesParseAsWritten) {
  const std::vector<std::uint64_t> holes{2, 4, 1u << 20};
  for (const EnvelopeHeader& h : {EnvelopeHeader{}, EnvelopeHeader{.ack = 99},
                                  EnvelopeHeader{.ack = 1, .resend = true, .missing = holes}}) {
    std::string out;
    append_keepalive_envelope(out, h);
    const v1::Envelope e = parse_one(out);
    expect_header(e, h);
    ASSERT_EQ(e.body_case(), v1::Envelope::kKeepalive);
    EXPECT_FALSE(e.keepalive().hello_please());
    EXPECT_EQ(out.size(), by_protobuf(e).size());
  }
}

// Keepalive.sent_through: written inside the Keepalive body, byte for byte as protobuf would.
TEST(EnvelopeCodec, AKeepaliveCarriesTheLastSeqWritten) {
  for (const std::uint64_t sent : {std::uint64_t{1}, std::uint64_t{300}, std::uint64_t{1} << 40}) {
    std::string out;
    append_keepalive_envelope(out, {.ack = 7}, sent);
    const v1::Envelope e = parse_one(out);
    ASSERT_EQ(e.body_case(), v1::Envelope::kKeepalive);
    EXPECT_EQ(e.keepalive().sent_through(), sent);
    EXPECT_EQ(e.ack(), 7u);
    EXPECT_EQ(out.size(), by_protobuf(e).size());
  }
}

TEST(EnvelopeCodec, EnvelopesFollowEachOtherOnOneStream) {
  std::string stream;
  const std::string payload(200, 'p');
  append_payload_envelope(stream, {.seq = 1, .ack = 2}, bytes_of(payload));
  append_keepalive_envelope(stream, {.ack = 3});
  append_payload_envelope(stream, {.unreliable_seq = 4}, {});
  DelimitedDecoder decoder;
  std::vector<v1::Envelope> got;
  decoder.feed(bytes_of(stream), [&](std::span<const std::uint8_t> m) {
    got.emplace_back().ParseFromArray(m.data(), static_cast<int>(m.size()));
  });
  ASSERT_EQ(got.size(), 3u);
  EXPECT_EQ(got[0].seq(), 1u);
  EXPECT_EQ(got[0].payload(), payload);
  EXPECT_EQ(got[1].ack(), 3u);
  EXPECT_TRUE(got[1].has_keepalive());
  EXPECT_EQ(got[2].unreliable_seq(), 4u);
  EXPECT_TRUE(got[2].payload().empty());
}

TEST(EnvelopeCodec, VarintSizesCoverSixtyFourBits) {
  EXPECT_EQ(varint_size(0), 1u);
  EXPECT_EQ(varint_size(127), 1u);
  EXPECT_EQ(varint_size(128), 2u);
  EXPECT_EQ(varint_size(std::uint64_t{1} << 35), 6u);
  EXPECT_EQ(varint_size(kHuge), 10u);
  std::uint8_t buffer[10];
  EXPECT_EQ(write_varint(kHuge, buffer), buffer + 10);
  EXPECT_EQ(buffer[9], 0x01);
}

}  // namespace
}  // namespace canbridge::backbone
