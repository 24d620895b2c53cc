// One direction of the emulated wireline: pacing, delay, jitter, bit errors and byte loss on a
// byte stream, as a pure core driven by the caller's clock.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <span>
#include <string>

#include "tools/link_emulator/seeded_random.hpp"

namespace canbridge::emulator {

using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;
using Duration = std::chrono::nanoseconds;

struct ImpairmentOptions {
  // Line rate in bits per second; 0 = unlimited (no pacing).
  std::uint64_t bandwidth_bps = 0;
  // Bits one byte occupies on the line: 10 is 8N1 serial (start bit, 8 data bits, stop bit).
  unsigned bits_per_byte = 10;
  // Fixed one-way delay added to every byte after it left the line.
  Duration latency{0};
  // Extra delay drawn uniformly from [0, jitter] once per pushed chunk. Delivery times never go
  // backwards, so jitter can stretch gaps but never reorders bytes.
  Duration jitter{0};
  // Each of a byte's 8 data bits is flipped independently with this probability.
  double bit_error_rate = 0.0;
  // Each byte is dropped with this probability (it still occupies its time on the line).
  double byte_loss_rate = 0.0;
  // Bytes held at most (queued for the line or in flight). A full buffer refuses input so that
  // the I/O layer stops reading and a TCP sender is slowed down like by a real slow line; it
  // should exceed bandwidth x latency or the latency itself limits the throughput.
  std::size_t buffer_limit = std::size_t{1} << 20;
  std::uint64_t seed = 1;
};

struct ImpairmentCounters {
  std::uint64_t bytes_in = 0;   // accepted by push()
  std::uint64_t bytes_out = 0;  // handed out by pop_due()
  std::uint64_t bits_flipped = 0;
  std::uint64_t bytes_lost = 0;  // byte_loss_rate
  std::uint64_t bytes_dropped_in_cut = 0;
  std::uint64_t bytes_dropped_on_disconnect = 0;
};

// Why held bytes are thrown away: the counters keep cuts apart from connections that closed.
enum class DiscardReason { cut, disconnect };

// Not thread-safe. Time only moves through the arguments, so tests drive it with any clock.
class Impairment {
 public:
  explicit Impairment(const ImpairmentOptions& options);

  // Takes up to free_space() bytes that arrived at `now` and returns how many it took; the rest
  // stay with the caller (back-pressure). Decides loss and bit errors at once; the outcome
  // depends only on the seed and the byte sequence, not on how it was split into chunks.
  std::size_t push(std::span<const std::uint8_t> bytes, TimePoint now);

  // When the oldest held byte is due; TimePoint::max() when nothing is held.
  TimePoint next_delivery() const;
  // Appends every held byte due at or before `now` to `out`, in order.
  void pop_due(TimePoint now, std::string& out);

  // Throws away every held byte (a cut or a closed connection) and frees the line at `now`.
  void discard_held(DiscardReason reason, TimePoint now);
  // Counts bytes that arrived while the line was cut and never entered it.
  void count_dropped_in_cut(std::size_t bytes) { counters_.bytes_dropped_in_cut += bytes; }

  std::size_t held() const { return bytes_.size(); }
  std::size_t free_space() const;
  const ImpairmentCounters& counters() const { return counters_; }
  const ImpairmentOptions& options() const { return options_; }

 private:
  // Consecutive held bytes that were serialised back to back with the same extra delay: byte k
  // of a run is due at base + (line_remainder + (k + 1) * byte_time_numerator) / bandwidth, exact
  // integer arithmetic, so pacing does not drift by rounding each byte's time.
  struct Run {
    TimePoint base;
    std::uint64_t line_remainder = 0;
    std::size_t count = 0;
    std::size_t delivered = 0;
  };

  TimePoint due_time(const Run& run, std::size_t index) const;
  std::size_t due_count(const Run& run, TimePoint now) const;
  // Moves the end of the line by one byte time.
  void occupy_line_for_one_byte();
  std::uint8_t corrupt(std::uint8_t byte);
  bool lose_next_byte();

  ImpairmentOptions options_;
  // Nanoseconds x bandwidth_bps that one byte occupies the line (bits_per_byte x 1e9).
  std::uint64_t byte_time_numerator_;
  // Runs longer than this would overflow due_time()'s arithmetic, so they are split.
  std::size_t max_run_length_;
  SeededRandom bit_error_random_;
  SeededRandom loss_random_;
  SeededRandom jitter_random_;
  std::uint64_t bits_before_next_flip_;
  std::uint64_t bytes_before_next_loss_;
  // The line is busy until line_free_ + line_remainder_ / bandwidth nanoseconds.
  TimePoint line_free_{};
  std::uint64_t line_remainder_ = 0;
  TimePoint last_due_ = TimePoint::min();
  std::deque<std::uint8_t> bytes_;
  std::deque<Run> runs_;
  ImpairmentCounters counters_;
};

}  // namespace canbridge::emulator
