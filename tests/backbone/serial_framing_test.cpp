#include "backbone/serial_framing.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "backbone/cobs.hpp"
#include "backbone/crc32c.hpp"

namespace canbridge::backbone {
namespace {

using Bytes = std::vector<std::uint8_t>;

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

Bytes to_bytes(const std::string& s) {
  return Bytes(s.begin(), s.end());
}

std::string to_string(std::span<const std::uint8_t> s) {
  return {reinterpret_cast<const char*>(s.data()), s.size()};
}

Bytes iota_bytes(std::size_t count, std::uint8_t first) {
  Bytes b(count);
  std::iota(b.begin(), b.end(), first);
  return b;
}

Bytes concat(std::initializer_list<Bytes> parts) {
  Bytes out;
  for (const Bytes& part : parts) out.insert(out.end(), part.begin(), part.end());
  return out;
}

// `zero_percent` of the bytes are zero, the rest uniformly 1..255.
Bytes random_bytes(std::mt19937& rng, std::size_t count, int zero_percent) {
  std::uniform_int_distribution<int> percent(0, 99);
  std::uniform_int_distribution<int> non_zero(1, 255);
  Bytes b(count);
  for (auto& byte : b) {
    byte = percent(rng) < zero_percent ? 0 : static_cast<std::uint8_t>(non_zero(rng));
  }
  return b;
}

std::string cobs(const Bytes& in) {
  std::string out;
  cobs_encode(in, out);
  return out;
}

std::string frame(const Bytes& payload) {
  std::string out;
  append_serial_frame(out, payload);
  return out;
}

// The textbook bit-at-a-time CRC-32C, as a reference for the table-driven one.
std::uint32_t bitwise_crc32c(const Bytes& data) {
  std::uint32_t crc = 0xFFFFFFFFu;
  for (std::uint8_t byte : data) {
    crc ^= byte;
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ ((crc & 1u) ? 0x82F63B78u : 0u);
  }
  return ~crc;
}

// Feeds `stream` in chunks of 1..max_chunk bytes and collects the payloads delivered.
std::vector<Bytes> deframe_in_chunks(SerialDeframer& deframer, const std::string& stream,
                                     std::mt19937& rng, std::size_t max_chunk) {
  std::vector<Bytes> delivered;
  std::uniform_int_distribution<std::size_t> chunk_size(1, max_chunk);
  std::span<const std::uint8_t> rest = bytes(stream);
  while (!rest.empty()) {
    const auto chunk = rest.first(std::min(chunk_size(rng), rest.size()));
    rest = rest.subspan(chunk.size());
    deframer.feed(chunk, [&](std::span<const std::uint8_t> payload) {
      delivered.emplace_back(payload.begin(), payload.end());
    });
  }
  return delivered;
}

std::vector<Bytes> deframe(SerialDeframer& deframer, const std::string& stream) {
  std::vector<Bytes> delivered;
  deframer.feed(bytes(stream), [&](std::span<const std::uint8_t> payload) {
    delivered.emplace_back(payload.begin(), payload.end());
  });
  return delivered;
}

std::uint64_t bad_frames(const DeframerCounters& c) {
  return c.crc_errors + c.cobs_errors + c.oversize + c.runts;
}

// ---------------------------------------------------------------------------------------------
// CRC-32C

TEST(Crc32c, MatchesTheCheckValue) {
  EXPECT_EQ(crc32c(bytes("123456789")), 0xE3069283u);
  EXPECT_EQ(crc32c({}), 0u);
}

TEST(Crc32c, MatchesTheIscsiTestVectors) {
  // RFC 3720, B.4: 32-byte messages, long enough to run through the sliced loop.
  EXPECT_EQ(crc32c(Bytes(32, 0x00)), 0x8A9136AAu);
  EXPECT_EQ(crc32c(Bytes(32, 0xFF)), 0x62A8AB43u);
  EXPECT_EQ(crc32c(iota_bytes(32, 0)), 0x46DD794Eu);
  Bytes descending = iota_bytes(32, 0);
  std::reverse(descending.begin(), descending.end());
  EXPECT_EQ(crc32c(descending), 0x113FDB5Cu);
}

TEST(Crc32c, MatchesTheBitwiseDefinitionForEveryLengthAndAlignment) {
  std::mt19937 rng(1);
  const Bytes data = random_bytes(rng, 300, 10);
  for (std::size_t offset = 0; offset < 8; ++offset) {
    for (std::size_t length = 0; offset + length <= 100; ++length) {
      const Bytes part(data.begin() + static_cast<std::ptrdiff_t>(offset),
                       data.begin() + static_cast<std::ptrdiff_t>(offset + length));
      ASSERT_EQ(crc32c(part), bitwise_crc32c(part)) << "offset " << offset << " length " << length;
    }
  }
  EXPECT_EQ(crc32c(data), bitwise_crc32c(data));
}

TEST(Crc32c, ChainsAcrossEverySplitPoint) {
  std::mt19937 rng(2);
  const Bytes data = random_bytes(rng, 77, 5);
  const std::uint32_t whole = crc32c(data);
  const std::span<const std::uint8_t> all(data);
  for (std::size_t split = 0; split <= data.size(); ++split) {
    EXPECT_EQ(crc32c(all.subspan(split), crc32c(all.first(split))), whole) << split;
  }
  EXPECT_EQ(crc32c(bytes("6789"), crc32c(bytes("12345"))), 0xE3069283u);
}

// ---------------------------------------------------------------------------------------------
// COBS

struct CobsVector {
  Bytes decoded;
  Bytes encoded;
};

// Wikipedia's "Encoding examples" (without the trailing delimiter), plus the empty message.
std::vector<CobsVector> cobs_vectors() {
  return {
      {{}, {0x01}},
      {{0x00}, {0x01, 0x01}},
      {{0x00, 0x00}, {0x01, 0x01, 0x01}},
      {{0x00, 0x11, 0x00}, {0x01, 0x02, 0x11, 0x01}},
      {{0x11, 0x22, 0x00, 0x33}, {0x03, 0x11, 0x22, 0x02, 0x33}},
      {{0x11, 0x22, 0x33, 0x44}, {0x05, 0x11, 0x22, 0x33, 0x44}},
      {{0x11, 0x00, 0x00, 0x00}, {0x02, 0x11, 0x01, 0x01, 0x01}},
      // 254 non-zero bytes: one full block, and no 0x01 block after it.
      {iota_bytes(254, 0x01), concat({{0xFF}, iota_bytes(254, 0x01)})},
      {concat({{0x00}, iota_bytes(254, 0x01)}), concat({{0x01, 0xFF}, iota_bytes(254, 0x01)})},
      // 255 non-zero bytes: a full block and a block of one.
      {iota_bytes(255, 0x01), concat({{0xFF}, iota_bytes(254, 0x01), {0x02, 0xFF}})},
      {concat({iota_bytes(254, 0x02), {0x00}}),
       concat({{0xFF}, iota_bytes(254, 0x02), {0x01, 0x01}})},
      {concat({iota_bytes(253, 0x03), {0x00, 0x01}}),
       concat({{0xFE}, iota_bytes(253, 0x03), {0x02, 0x01}})},
  };
}

TEST(Cobs, EncodesTheKnownVectors) {
  for (const CobsVector& v : cobs_vectors()) {
    SCOPED_TRACE(v.decoded.size());
    EXPECT_EQ(to_bytes(cobs(v.decoded)), v.encoded);
    EXPECT_LE(v.encoded.size(), cobs_max_encoded_size(v.decoded.size()));
  }
}

TEST(Cobs, DecodesTheKnownVectors) {
  for (const CobsVector& v : cobs_vectors()) {
    SCOPED_TRACE(v.decoded.size());
    Bytes decoded;
    ASSERT_TRUE(cobs_decode(v.encoded, decoded));
    EXPECT_EQ(decoded, v.decoded);
  }
}

TEST(Cobs, EncodeAndDecodeAppend) {
  std::string encoded = "x";
  cobs_encode(Bytes{0x11, 0x00}, encoded);
  EXPECT_EQ(encoded, std::string("x\x02\x11\x01", 4));
  Bytes decoded{0xAA};
  ASSERT_TRUE(cobs_decode(Bytes{0x02, 0x11, 0x01}, decoded));
  EXPECT_EQ(decoded, (Bytes{0xAA, 0x11, 0x00}));
}

TEST(Cobs, RoundTripsRandomMessagesOfEverySize) {
  std::mt19937 rng(3);
  for (std::size_t size = 0; size <= 1000; ++size) {
    for (int zero_percent : {0, 1, 30, 100}) {
      const Bytes message = random_bytes(rng, size, zero_percent);
      const std::string encoded = cobs(message);
      ASSERT_EQ(encoded.find('\0'), std::string::npos) << size;
      ASSERT_LE(encoded.size(), cobs_max_encoded_size(size)) << size;
      Bytes decoded;
      ASSERT_TRUE(cobs_decode(bytes(encoded), decoded)) << size;
      ASSERT_EQ(decoded, message) << size << " bytes, " << zero_percent << "% zeros";
    }
  }
}

TEST(Cobs, RoundTripsRunsAroundTheBlockLimit) {
  std::mt19937 rng(4);
  for (std::size_t run : {253u, 254u, 255u, 507u, 508u, 509u, 762u}) {
    for (const Bytes& prefix : {Bytes{}, Bytes{0x00}, Bytes{0x07}, Bytes{0x07, 0x00}}) {
      for (const Bytes& suffix : {Bytes{}, Bytes{0x00}, Bytes{0x00, 0x09}, Bytes{0x00, 0x00}}) {
        const Bytes message = concat({prefix, random_bytes(rng, run, 0), suffix});
        SCOPED_TRACE(::testing::Message() << "run " << run << " prefix " << prefix.size()
                                          << " suffix " << suffix.size());
        const std::string encoded = cobs(message);
        EXPECT_EQ(encoded.find('\0'), std::string::npos);
        EXPECT_LE(encoded.size(), cobs_max_encoded_size(message.size()));
        Bytes decoded;
        ASSERT_TRUE(cobs_decode(bytes(encoded), decoded));
        EXPECT_EQ(decoded, message);
      }
    }
  }
  // The bound is exact for n non-zero bytes below one block, and for whole blocks plus one.
  EXPECT_EQ(cobs(random_bytes(rng, 253, 0)).size(), cobs_max_encoded_size(253));
  EXPECT_EQ(cobs(random_bytes(rng, 255, 0)).size(), cobs_max_encoded_size(255));
}

TEST(Cobs, EncoderFedInPiecesMatchesOneShot) {
  std::mt19937 rng(5);
  for (int round = 0; round < 300; ++round) {
    const Bytes message = random_bytes(rng, rng() % 800, static_cast<int>(rng() % 3));
    std::string pieces;
    CobsEncoder encoder(pieces);
    std::span<const std::uint8_t> rest(message);
    while (!rest.empty()) {
      const auto piece = rest.first(std::min<std::size_t>(rng() % 300, rest.size()));
      encoder.add(piece);
      rest = rest.subspan(piece.size());
    }
    encoder.finish();
    ASSERT_EQ(pieces, cobs(message)) << round;
  }
}

TEST(Cobs, AcceptsTheTrailingEmptyBlockAfterAFullOne) {
  // Other encoders end a message of 254 non-zero bytes with an extra 0x01 block.
  Bytes decoded;
  ASSERT_TRUE(cobs_decode(concat({{0xFF}, iota_bytes(254, 0x01), {0x01}}), decoded));
  EXPECT_EQ(decoded, iota_bytes(254, 0x01));
}

TEST(Cobs, RejectsMalformedEncodings) {
  const std::vector<Bytes> malformed = {
      {},                                       // not even a code byte
      {0x00},                                   // a zero code
      {0x01, 0x00},                             // a zero inside
      {0x03, 0x11, 0x00},                       // a zero among the data
      {0x03, 0x11, 0x22, 0x00, 0x01},           // a zero as a code byte
      {0x02},                                   // a code pointing past the end
      {0x05, 0x11, 0x22, 0x33},                 // ... by one byte
      {0x02, 0x11, 0x04, 0x22},                 // ... in a later block
      concat({{0xFF}, iota_bytes(253, 0x01)}),  // a full block one byte short
  };
  for (const Bytes& encoded : malformed) {
    SCOPED_TRACE(::testing::PrintToString(encoded));
    Bytes decoded{0xAB, 0xCD};
    EXPECT_FALSE(cobs_decode(encoded, decoded));
    EXPECT_EQ(decoded, (Bytes{0xAB, 0xCD})) << "a failed decode must leave the output alone";
  }
}

// ---------------------------------------------------------------------------------------------
// Serial framing

TEST(SerialFraming, FrameIsCobsOfPayloadAndLittleEndianCrcThenDelimiter) {
  const std::string f = frame(to_bytes("123456789"));
  ASSERT_FALSE(f.empty());
  EXPECT_EQ(f.back(), '\0');
  EXPECT_EQ(f.find('\0'), f.size() - 1) << "the delimiter is the only zero byte";
  EXPECT_LE(f.size(), serial_frame_max_size(9));
  Bytes decoded;
  ASSERT_TRUE(cobs_decode(bytes(f.substr(0, f.size() - 1)), decoded));
  EXPECT_EQ(decoded, concat({to_bytes("123456789"), {0x83, 0x92, 0x06, 0xE3}}));

  // An empty payload still carries its CRC (which is 0 for the empty message).
  EXPECT_EQ(frame({}), std::string("\x01\x01\x01\x01\x01\x00", 6));
}

TEST(SerialFraming, AppendsToWhatIsThere) {
  std::string out = "xy";
  append_serial_frame(out, Bytes{1, 2, 3});
  EXPECT_EQ(out, "xy" + frame(Bytes{1, 2, 3}));
}

TEST(SerialDeframer, RoundTripsFramesFedInRandomChunks) {
  std::mt19937 rng(6);
  std::vector<Bytes> sent;
  std::string stream;
  for (int i = 0; i < 400; ++i) {
    sent.push_back(random_bytes(rng, rng() % 600, static_cast<int>(rng() % 4) * 10));
    append_serial_frame(stream, sent.back());
  }
  for (std::size_t max_chunk : {1u, 2u, 7u, 64u, 1000u, 100000u}) {
    SCOPED_TRACE(max_chunk);
    SerialDeframer deframer(600);
    EXPECT_EQ(deframe_in_chunks(deframer, stream, rng, max_chunk), sent);
    const DeframerCounters& c = deframer.counters();
    EXPECT_EQ(c.frames, sent.size());
    EXPECT_EQ(bad_frames(c), 0u);
    EXPECT_EQ(c.discarded_bytes, 0u);
    EXPECT_EQ(deframer.pending_bytes(), 0u);
  }
}

TEST(SerialDeframer, NextStopsAfterEachPayloadAndResumesWithTheRest) {
  const std::vector<Bytes> sent = {{1, 2, 3}, {}, {0, 0, 0}, {4}};
  std::string stream;
  for (const Bytes& p : sent) append_serial_frame(stream, p);
  SerialDeframer deframer(16);
  std::span<const std::uint8_t> input = bytes(stream);
  std::size_t offset = 0;
  for (const Bytes& expected : sent) {
    const auto payload = deframer.next(input);
    ASSERT_TRUE(payload.has_value());
    EXPECT_EQ(Bytes(payload->begin(), payload->end()), expected);
    offset += frame(expected).size();
    EXPECT_EQ(input.size(), stream.size() - offset) << "consumed exactly up to the delimiter";
  }
  EXPECT_FALSE(deframer.next(input).has_value());
  EXPECT_TRUE(input.empty());
}

TEST(SerialDeframer, EmptyFramesAreNeitherErrorsNorDiscarded) {
  const std::string stream = std::string(3, '\0') + frame({7, 8}) + std::string(2, '\0') +
                             frame({9}) + std::string(1, '\0');
  SerialDeframer deframer(16);
  EXPECT_EQ(deframe(deframer, stream), (std::vector<Bytes>{{7, 8}, {9}}));
  EXPECT_EQ(deframer.counters().frames, 2u);
  EXPECT_EQ(bad_frames(deframer.counters()), 0u);
  EXPECT_EQ(deframer.counters().discarded_bytes, 0u);
}

TEST(SerialDeframer, DeliversAnEmptyPayload) {
  SerialDeframer deframer(16);
  EXPECT_EQ(deframe(deframer, frame({})), (std::vector<Bytes>{Bytes{}}));
}

TEST(SerialDeframer, LeadingDelimiterFlushesAPartialFrame) {
  const std::string cut = frame({1, 2, 3, 4, 5, 6}).substr(0, 5);
  SerialDeframer deframer(16);
  const std::string stream = cut + '\0' + frame({7});
  EXPECT_EQ(deframe(deframer, stream), (std::vector<Bytes>{{7}}));
  EXPECT_EQ(bad_frames(deframer.counters()), 1u);
  EXPECT_EQ(deframer.counters().discarded_bytes, cut.size() + 1);
}

TEST(SerialDeframer, CountsEachKindOfBadFrameOnceAndResynchronises) {
  const std::string good = frame({0x42, 0x00, 0x43});
  struct Case {
    const char* name;
    std::string bad;
    std::uint64_t DeframerCounters::*counter;
  };
  std::string corrupted = frame({1, 2, 3, 4, 5});
  corrupted[3] = static_cast<char>(corrupted[3] ^ 0x10);
  const std::vector<Case> cases = {
      {"runt: decodes to nothing", std::string("\x01\x00", 2), &DeframerCounters::runts},
      {"runt: 3 bytes", std::string("\x04\x01\x02\x03\x00", 5), &DeframerCounters::runts},
      {"block cut short", std::string("\x05\x11\x22\x00", 4), &DeframerCounters::cobs_errors},
      {"bit flip", corrupted, &DeframerCounters::crc_errors},
      // Which check catches the merged frame depends on the bytes; exactly one must.
      {"cut frame merged into the next", frame({1, 2, 3}).substr(0, 3) + frame({4, 5, 6}), nullptr},
      {"four zero bytes, wrong CRC", std::string("\x01\x01\x01\x02\x01\x00", 6),
       &DeframerCounters::crc_errors},
      {"oversize", frame(Bytes(17, 0x33)), &DeframerCounters::oversize},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    SerialDeframer deframer(16);
    const std::string stream = good + c.bad + good;
    EXPECT_EQ(deframe(deframer, stream),
              (std::vector<Bytes>{{0x42, 0x00, 0x43}, {0x42, 0x00, 0x43}}));
    const DeframerCounters& counters = deframer.counters();
    if (c.counter) {
      EXPECT_EQ(counters.*c.counter, 1u);
    }
    EXPECT_EQ(bad_frames(counters), 1u);
    EXPECT_EQ(counters.discarded_bytes, c.bad.size());
  }
}

TEST(SerialDeframer, ResynchronisesAfterGarbage) {
  std::mt19937 rng(7);
  const Bytes payload = {0xDE, 0xAD, 0x00, 0xBE, 0xEF};
  for (int round = 0; round < 200; ++round) {
    const Bytes garbage = random_bytes(rng, rng() % 3000, static_cast<int>(rng() % 5));
    const std::string stream = to_string(garbage) + '\0' + frame(payload);
    SerialDeframer deframer(64);
    const auto delivered = deframe_in_chunks(deframer, stream, rng, 50);
    ASSERT_FALSE(delivered.empty()) << "round " << round;
    EXPECT_EQ(delivered.back(), payload);
    EXPECT_EQ(deframer.counters().frames, delivered.size());
  }
}

TEST(SerialDeframer, AcceptsPayloadsUpToTheMaximumAndSkipsLargerOnes) {
  std::mt19937 rng(8);
  for (std::size_t max : {0u, 1u, 100u, 249u, 250u, 251u, 500u, 504u, 1000u}) {
    for (int zero_percent : {0, 20}) {
      for (std::size_t size = max > 2 ? max - 2 : 0; size <= max + 2; ++size) {
        SCOPED_TRACE(::testing::Message()
                     << "max " << max << " size " << size << " zeros " << zero_percent << "%");
        const Bytes payload = random_bytes(rng, size, zero_percent);
        SerialDeframer deframer(max);
        const auto delivered = deframe(deframer, frame(payload) + frame({}));
        if (size <= max) {
          EXPECT_EQ(delivered, (std::vector<Bytes>{payload, Bytes{}}));
          EXPECT_EQ(deframer.counters().oversize, 0u);
        } else {
          EXPECT_EQ(delivered, (std::vector<Bytes>{Bytes{}}));
          EXPECT_EQ(deframer.counters().oversize, 1u);
          EXPECT_EQ(deframer.counters().discarded_bytes, frame(payload).size());
        }
        EXPECT_LE(deframer.buffer_capacity(), 2 * (max + kFrameCrcSize));
      }
    }
  }
}

TEST(SerialDeframer, OversizeRunKeepsMemoryBoundedAndCountsOnce) {
  constexpr std::size_t kMax = 100;
  SerialDeframer deframer(kMax);
  std::mt19937 rng(9);
  const std::string babble = to_string(random_bytes(rng, 4096, 0));
  for (int i = 0; i < 2560; ++i) {  // 10 MiB without a delimiter
    deframer.feed(bytes(babble), [](std::span<const std::uint8_t>) { FAIL(); });
    ASSERT_LE(deframer.buffer_capacity(), 2 * (kMax + kFrameCrcSize));
  }
  EXPECT_EQ(deframer.pending_bytes(), 2560u * 4096u);
  const auto delivered = deframe(deframer, std::string(1, '\0') + frame({1, 2}));
  EXPECT_EQ(delivered, (std::vector<Bytes>{{1, 2}}));
  EXPECT_EQ(deframer.counters().oversize, 1u);
  EXPECT_EQ(bad_frames(deframer.counters()), 1u);
  EXPECT_EQ(deframer.counters().discarded_bytes, 2560u * 4096u + 1u);
}

TEST(SerialDeframer, DoesNotGrowItsBufferInSteadyState) {
  std::mt19937 rng(10);
  SerialDeframer deframer(512);
  deframe(deframer, frame(random_bytes(rng, 512, 0)));
  const std::size_t capacity = deframer.buffer_capacity();
  std::string stream;
  for (int i = 0; i < 500; ++i) append_serial_frame(stream, random_bytes(rng, rng() % 513, 10));
  deframe_in_chunks(deframer, stream, rng, 100);
  EXPECT_EQ(deframer.counters().frames, 501u);
  EXPECT_EQ(deframer.buffer_capacity(), capacity);
}

TEST(SerialDeframer, ResetDropsThePartialFrameAndTheCounters) {
  SerialDeframer deframer(16);
  deframe(deframer, std::string("\x02\x11\x00", 3) + frame({1}).substr(0, 2));
  ASSERT_EQ(deframer.counters().runts, 1u);
  ASSERT_EQ(deframer.pending_bytes(), 2u);
  deframer.reset();
  EXPECT_EQ(deframer.pending_bytes(), 0u);
  EXPECT_EQ(deframer.counters().runts, 0u);
  EXPECT_EQ(deframe(deframer, frame({5, 6})), (std::vector<Bytes>{{5, 6}}));
  EXPECT_EQ(bad_frames(deframer.counters()), 0u);
}

// A noisy line: many frames, some corrupted in each way a serial link can. Whatever is
// delivered must be exactly what was sent, in order; every frame that reached the receiver
// intact after a delimiter must be delivered; and the counters must account for every byte.
TEST(SerialDeframer, NoisyLinePropertyHolds) {
  constexpr std::size_t kMax = 512;
  enum Damage { intact, flip_bits, drop_bytes, garbage_before, cut, runt, kinds };
  for (std::uint32_t seed = 100; seed < 112; ++seed) {
    SCOPED_TRACE(seed);
    std::mt19937 rng(seed);
    std::vector<Bytes> sent;
    std::vector<bool> must_arrive;
    std::string stream;
    for (std::uint32_t index = 0; index < 600; ++index) {
      // Every payload starts with its index so that it is unique; some are oversize.
      Bytes payload = random_bytes(rng, 4 + rng() % (kMax + 40), static_cast<int>(rng() % 3) * 5);
      for (int i = 0; i < 4; ++i) payload[static_cast<std::size_t>(i)] = (index >> (8 * i)) & 0xFF;
      std::string line = frame(payload);
      const auto damage = rng() % 3 == 0 ? static_cast<Damage>(1 + rng() % (kinds - 1)) : intact;
      switch (damage) {
        case intact:
        case kinds:
          break;
        case flip_bits:
          for (std::uint32_t n = 1 + rng() % 3; n > 0; --n) {
            line[rng() % line.size()] ^= static_cast<char>(1u << (rng() % 8));
          }
          break;
        case drop_bytes:
          for (std::uint32_t n = 1 + rng() % 3; n > 0 && !line.empty(); --n) {
            line.erase(rng() % line.size(), 1);
          }
          break;
        case garbage_before: {
          stream += to_string(random_bytes(rng, rng() % 300, static_cast<int>(rng() % 3)));
          if (rng() % 2 == 0) stream += '\0';  // the sender's flush
          break;
        }
        case cut:
          line.resize(rng() % line.size());
          break;
        case runt:
          stream += frame(payload).substr(0, 1 + rng() % 3) + '\0';
          break;
      }
      // Intact and starting right after a delimiter: nothing can excuse losing this one.
      const bool clean_start = stream.empty() || stream.back() == '\0';
      sent.push_back(payload);
      must_arrive.push_back(damage != flip_bits && damage != drop_bytes && damage != cut &&
                            clean_start && payload.size() <= kMax);
      stream += line;
    }
    stream += '\0';  // ends whatever frame was left open

    SerialDeframer deframer(kMax);
    const auto delivered = deframe_in_chunks(deframer, stream, rng, 97);

    // In order, bit-exact, nothing invented, nothing intact lost.
    std::size_t next_sent = 0;
    for (const Bytes& payload : delivered) {
      ASSERT_GE(payload.size(), 4u);
      const std::uint32_t index =
          payload[0] | (payload[1] << 8) | (payload[2] << 16) | (std::uint32_t{payload[3]} << 24);
      ASSERT_LT(index, sent.size());
      ASSERT_GE(index, next_sent) << "delivered out of order or twice";
      ASSERT_EQ(payload, sent[index]) << "corrupted payload delivered";
      for (; next_sent < index; ++next_sent) {
        EXPECT_FALSE(must_arrive[next_sent]) << "intact frame " << next_sent << " lost";
      }
      next_sent = index + 1;
    }
    for (; next_sent < sent.size(); ++next_sent) EXPECT_FALSE(must_arrive[next_sent]);

    // The counters account for every frame and every byte of the stream.
    std::uint64_t empty_frames = 0;
    std::uint64_t delimiters = 0;
    for (std::size_t i = 0; i < stream.size(); ++i) {
      if (stream[i] != '\0') continue;
      ++delimiters;
      if (i == 0 || stream[i - 1] == '\0') ++empty_frames;
    }
    const DeframerCounters& c = deframer.counters();
    EXPECT_EQ(c.frames, delivered.size());
    EXPECT_EQ(c.frames + bad_frames(c), delimiters - empty_frames);
    std::uint64_t delivered_line_bytes = 0;
    for (const Bytes& payload : delivered) delivered_line_bytes += frame(payload).size();
    EXPECT_EQ(delivered_line_bytes + c.discarded_bytes + empty_frames, stream.size());
    EXPECT_EQ(deframer.pending_bytes(), 0u);
    // The run exercised every kind of loss.
    EXPECT_GT(c.crc_errors, 0u);
    EXPECT_GT(c.cobs_errors, 0u);
    EXPECT_GT(c.oversize, 0u);
    EXPECT_GT(c.runts, 0u);
    EXPECT_GT(c.frames, 300u);

    // Chunking does not change the outcome.
    SerialDeframer whole(kMax);
    EXPECT_EQ(deframe(whole, stream), delivered);
    EXPECT_EQ(whole.counters().discarded_bytes, c.discarded_bytes);
    EXPECT_EQ(whole.counters().crc_errors, c.crc_errors);
  }
}

}  // namespace
}  // namespace canbridge::backbone
