#include "tools/link_emulator/impairment.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

namespace canbridge::emulator {
namespace {

using namespace std::chrono_literals;

const TimePoint kStart = TimePoint{} + 1h;

std::vector<std::uint8_t> random_bytes(std::size_t n, std::uint32_t seed = 42) {
  std::mt19937 engine(seed);
  std::vector<std::uint8_t> bytes(n);
  for (auto& byte : bytes) byte = static_cast<std::uint8_t>(engine());
  return bytes;
}

// Everything the line holds, taking emulated time straight to each next delivery.
std::string drain(Impairment& line) {
  std::string out;
  while (line.held() > 0) line.pop_due(line.next_delivery(), out);
  return out;
}

std::uint64_t differing_bits(const std::vector<std::uint8_t>& sent, const std::string& received) {
  std::uint64_t bits = 0;
  for (std::size_t i = 0; i < sent.size(); ++i) {
    bits += static_cast<std::uint64_t>(
        std::popcount(static_cast<unsigned>(sent[i] ^ static_cast<std::uint8_t>(received[i]))));
  }
  return bits;
}

TEST(Impairment, UnlimitedBandwidthWithoutDelayDeliversAtOnce) {
  Impairment line({});
  const auto bytes = random_bytes(5000);
  EXPECT_EQ(line.push(bytes, kStart), bytes.size());
  EXPECT_EQ(line.next_delivery(), kStart);
  std::string out;
  line.pop_due(kStart, out);
  EXPECT_EQ(out, std::string(bytes.begin(), bytes.end()));
  EXPECT_EQ(line.held(), 0u);
  EXPECT_EQ(line.next_delivery(), TimePoint::max());
  EXPECT_EQ(line.counters().bytes_in, 5000u);
  EXPECT_EQ(line.counters().bytes_out, 5000u);
}

TEST(Impairment, BandwidthPacesBytesExactly) {
  ImpairmentOptions options;
  options.bandwidth_bps = 115200;  // 10 bits per byte by default: 86.805 us per byte
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(1000), kStart), 1000u);
  EXPECT_EQ(line.next_delivery(), kStart + 86805ns);
  // 1000 x 10 bits / 115200 bit/s = 86.8055... ms, without drift from rounding each byte.
  const TimePoint last = kStart + 86805555ns;
  std::string out;
  line.pop_due(last - 1ns, out);
  EXPECT_EQ(out.size(), 999u);
  EXPECT_EQ(line.next_delivery(), last);
  line.pop_due(last, out);
  EXPECT_EQ(out.size(), 1000u);
}

TEST(Impairment, BandwidthSerialisesChunksThatArriveWhileTheLineIsBusy) {
  ImpairmentOptions options;
  options.bandwidth_bps = 115200;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(100), kStart), 100u);
  ASSERT_EQ(line.push(random_bytes(100), kStart + 1ms), 100u);  // the line is busy for 8.68 ms
  std::string out;
  line.pop_due(kStart + 17361110ns, out);
  EXPECT_EQ(out.size(), 199u);
  line.pop_due(kStart + 17361111ns, out);  // 200 x 10 / 115200 s
  EXPECT_EQ(out.size(), 200u);
  // An idle line starts the next chunk when it arrives.
  ASSERT_EQ(line.push(random_bytes(1), kStart + 1s), 1u);
  EXPECT_EQ(line.next_delivery(), kStart + 1s + 86805ns);
}

TEST(Impairment, BitsPerByteSetTheByteTime) {
  ImpairmentOptions options;
  options.bandwidth_bps = 8000;
  options.bits_per_byte = 8;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(10), kStart), 10u);
  std::string out;
  line.pop_due(kStart + 10ms, out);
  EXPECT_EQ(out.size(), 10u);
  EXPECT_EQ(line.counters().bytes_out, 10u);
}

TEST(Impairment, LatencyDelaysEveryByte) {
  ImpairmentOptions options;
  options.latency = 50ms;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(10), kStart), 10u);
  EXPECT_EQ(line.next_delivery(), kStart + 50ms);
  std::string out;
  line.pop_due(kStart + 50ms - 1ns, out);
  EXPECT_TRUE(out.empty());
  line.pop_due(kStart + 50ms, out);
  EXPECT_EQ(out.size(), 10u);
}

TEST(Impairment, LatencyAddsToTheTimeOnTheLine) {
  ImpairmentOptions options;
  options.bandwidth_bps = 9600;
  options.latency = 20ms;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(96), kStart), 96u);  // 100 ms on the line
  EXPECT_EQ(line.next_delivery(), kStart + 1041666ns + 20ms);
  std::string out;
  line.pop_due(kStart + 120ms - 1ns, out);
  EXPECT_EQ(out.size(), 95u);
  line.pop_due(kStart + 120ms, out);
  EXPECT_EQ(out.size(), 96u);
}

TEST(Impairment, JitterStaysInRangeAndNeverReorders) {
  ImpairmentOptions options;
  options.latency = 5ms;
  options.jitter = 10ms;
  options.seed = 3;
  Impairment line(options);
  constexpr int kBytes = 500;
  std::vector<TimePoint> pushed;
  std::vector<TimePoint> delivered;
  std::string out;
  // One byte per millisecond; deliveries are taken at exactly their due time.
  for (int i = 0; i < kBytes || line.held() > 0;) {
    const TimePoint next_push = i < kBytes ? kStart + i * 1ms : TimePoint::max();
    if (line.next_delivery() <= next_push) {
      const TimePoint now = line.next_delivery();
      const std::size_t before = out.size();
      line.pop_due(now, out);
      delivered.insert(delivered.end(), out.size() - before, now);
    } else {
      const std::uint8_t byte = static_cast<std::uint8_t>(i);
      ASSERT_EQ(line.push(std::span(&byte, 1), next_push), 1u);
      pushed.push_back(next_push);
      ++i;
    }
  }
  ASSERT_EQ(out.size(), static_cast<std::size_t>(kBytes));
  std::vector<Duration> delays;
  for (int i = 0; i < kBytes; ++i) {
    EXPECT_EQ(static_cast<std::uint8_t>(out[static_cast<std::size_t>(i)]),
              static_cast<std::uint8_t>(i));
    if (i > 0) {
      EXPECT_GE(delivered[static_cast<std::size_t>(i)], delivered[static_cast<std::size_t>(i - 1)]);
    }
    const Duration delay =
        delivered[static_cast<std::size_t>(i)] - pushed[static_cast<std::size_t>(i)];
    EXPECT_GE(delay, 5ms);
    EXPECT_LE(delay, 15ms);
    delays.push_back(delay);
  }
  std::sort(delays.begin(), delays.end());
  EXPECT_GT(delays.back() - delays.front(), 5ms) << "jitter should spread the delays";
}

TEST(Impairment, BitErrorRateFollowsTheBinomialDistribution) {
  ImpairmentOptions options;
  options.bit_error_rate = 1e-4;
  options.buffer_limit = 2'000'000;
  options.seed = 11;
  Impairment line(options);
  const auto bytes = random_bytes(1'250'000);  // 10^7 data bits
  ASSERT_EQ(line.push(bytes, kStart), bytes.size());
  const std::string out = drain(line);
  ASSERT_EQ(out.size(), bytes.size());
  const std::uint64_t flipped = differing_bits(bytes, out);
  EXPECT_EQ(flipped, line.counters().bits_flipped);
  // Mean 1000, standard deviation ~31.6: five deviations either side.
  const double sigma = std::sqrt(1e7 * 1e-4 * (1 - 1e-4));
  EXPECT_GT(static_cast<double>(flipped), 1000 - 5 * sigma);
  EXPECT_LT(static_cast<double>(flipped), 1000 + 5 * sigma);
}

TEST(Impairment, ZeroBitErrorRateFlipsNothing) {
  ImpairmentOptions options;
  options.buffer_limit = 2'000'000;
  Impairment line(options);
  const auto bytes = random_bytes(1'250'000);
  ASSERT_EQ(line.push(bytes, kStart), bytes.size());
  EXPECT_EQ(drain(line), std::string(bytes.begin(), bytes.end()));
  EXPECT_EQ(line.counters().bits_flipped, 0u);
}

TEST(Impairment, BitErrorRateOneFlipsEveryBit) {
  ImpairmentOptions options;
  options.bit_error_rate = 1.0;
  Impairment line(options);
  const std::vector<std::uint8_t> bytes{0x00, 0xFF, 0x5A};
  ASSERT_EQ(line.push(bytes, kStart), 3u);
  EXPECT_EQ(drain(line), std::string("\xFF\x00\xA5", 3));
  EXPECT_EQ(line.counters().bits_flipped, 24u);
}

TEST(Impairment, ByteLossRateFollowsTheBinomialDistribution) {
  ImpairmentOptions options;
  options.byte_loss_rate = 0.01;
  options.seed = 5;
  Impairment line(options);
  const auto bytes = random_bytes(1'000'000);
  ASSERT_EQ(line.push(bytes, kStart), bytes.size());
  const std::string out = drain(line);
  const std::uint64_t lost = line.counters().bytes_lost;
  EXPECT_EQ(out.size() + lost, bytes.size());
  const double sigma = std::sqrt(1e6 * 0.01 * 0.99);  // ~99.5
  EXPECT_GT(static_cast<double>(lost), 10000 - 5 * sigma);
  EXPECT_LT(static_cast<double>(lost), 10000 + 5 * sigma);
  EXPECT_EQ(line.counters().bytes_out, out.size());
}

TEST(Impairment, LostBytesStillTakeTheirTimeOnTheLine) {
  ImpairmentOptions options;
  options.bandwidth_bps = 10000;  // 1 ms per byte
  options.byte_loss_rate = 0.5;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(100), kStart), 100u);
  const std::uint64_t lost = line.counters().bytes_lost;
  ASSERT_GT(lost, 0u);
  ASSERT_GT(line.held(), 0u);
  std::string out;
  line.pop_due(kStart + 100ms, out);
  EXPECT_EQ(out.size(), 100u - lost);
  // Bytes pushed now queue behind all 100, lost ones included: the first that is not lost
  // leaves the line after 100 ms plus its own position.
  std::size_t position = 100;
  while (line.held() == 0) {
    const std::uint8_t byte = 0x55;
    ASSERT_EQ(line.push(std::span(&byte, 1), kStart), 1u);
    ++position;
  }
  EXPECT_EQ(line.next_delivery(),
            kStart + std::chrono::milliseconds(static_cast<std::int64_t>(position)));
}

TEST(Impairment, SameSeedGivesTheSameOutputHoweverTheInputIsChunked) {
  ImpairmentOptions options;
  options.bit_error_rate = 1e-3;
  options.byte_loss_rate = 1e-3;
  options.seed = 7;
  const auto bytes = random_bytes(100'000);

  Impairment whole(options);
  ASSERT_EQ(whole.push(bytes, kStart), bytes.size());
  const std::string expected = drain(whole);

  Impairment chunked(options);
  std::mt19937 sizes(1);
  std::string out;
  TimePoint now = kStart;
  for (std::size_t at = 0; at < bytes.size();) {
    const std::size_t n = std::min<std::size_t>(1 + sizes() % 1000, bytes.size() - at);
    ASSERT_EQ(chunked.push(std::span(bytes).subspan(at, n), now), n);
    at += n;
    now += 1ms;
    chunked.pop_due(now, out);
  }
  out += drain(chunked);
  EXPECT_EQ(out, expected);
  EXPECT_EQ(chunked.counters().bits_flipped, whole.counters().bits_flipped);
  EXPECT_EQ(chunked.counters().bytes_lost, whole.counters().bytes_lost);

  options.seed = 8;
  Impairment other(options);
  ASSERT_EQ(other.push(bytes, kStart), bytes.size());
  EXPECT_NE(drain(other), expected);
}

TEST(Impairment, FullBufferPushesBack) {
  ImpairmentOptions options;
  options.bandwidth_bps = 10000;  // 1 ms per byte
  options.buffer_limit = 1000;
  Impairment line(options);
  const auto bytes = random_bytes(1500);
  EXPECT_EQ(line.push(bytes, kStart), 1000u);
  EXPECT_EQ(line.free_space(), 0u);
  EXPECT_EQ(line.push(std::span(bytes).subspan(1000), kStart), 0u);
  EXPECT_EQ(line.counters().bytes_in, 1000u);
  std::string out;
  line.pop_due(kStart + 10ms, out);
  EXPECT_EQ(out.size(), 10u);
  EXPECT_EQ(line.free_space(), 10u);
  EXPECT_EQ(line.push(std::span(bytes).subspan(1000), kStart + 10ms), 10u);
}

TEST(Impairment, DiscardingCountsTheReasonAndFreesTheLine) {
  ImpairmentOptions options;
  options.bandwidth_bps = 10000;
  Impairment line(options);
  ASSERT_EQ(line.push(random_bytes(100), kStart), 100u);
  line.discard_held(DiscardReason::cut, kStart + 10ms);
  EXPECT_EQ(line.held(), 0u);
  EXPECT_EQ(line.next_delivery(), TimePoint::max());
  EXPECT_EQ(line.counters().bytes_dropped_in_cut, 100u);
  line.count_dropped_in_cut(5);
  EXPECT_EQ(line.counters().bytes_dropped_in_cut, 105u);
  // The line is free again at once, not after the 100 ms of discarded bytes.
  ASSERT_EQ(line.push(random_bytes(1), kStart + 20ms), 1u);
  EXPECT_EQ(line.next_delivery(), kStart + 21ms);
  line.discard_held(DiscardReason::disconnect, kStart + 20ms);
  EXPECT_EQ(line.counters().bytes_dropped_on_disconnect, 1u);
  EXPECT_EQ(line.counters().bytes_dropped_in_cut, 105u);
}

}  // namespace
}  // namespace canbridge::emulator
