#include "tools/link_emulator/impairment.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>

namespace canbridge::emulator {

namespace {

constexpr std::uint64_t kNanosecondsPerSecond = 1'000'000'000;

std::uint64_t saturating_add(std::uint64_t a, std::uint64_t b) {
  return a > std::numeric_limits<std::uint64_t>::max() - b
             ? std::numeric_limits<std::uint64_t>::max()
             : a + b;
}

}  // namespace

Impairment::Impairment(const ImpairmentOptions& options)
    : options_(options),
      byte_time_numerator_(std::uint64_t{options.bits_per_byte} * kNanosecondsPerSecond),
      max_run_length_(std::numeric_limits<std::size_t>::max()),
      bit_error_random_(derive_seed(options.seed, 1)),
      loss_random_(derive_seed(options.seed, 2)),
      jitter_random_(derive_seed(options.seed, 3)),
      bits_before_next_flip_(bit_error_random_.failures_before_success(options.bit_error_rate)),
      bytes_before_next_loss_(loss_random_.failures_before_success(options.byte_loss_rate)) {
  if (options.bits_per_byte == 0 || options.bits_per_byte > 64) {
    throw std::invalid_argument("bits per byte must be 1..64");
  }
  if (options.latency < Duration::zero() || options.jitter < Duration::zero()) {
    throw std::invalid_argument("latency and jitter must not be negative");
  }
  if (options.bandwidth_bps > 0) {
    const std::uint64_t headroom =
        std::numeric_limits<std::uint64_t>::max() - options.bandwidth_bps;
    max_run_length_ = static_cast<std::size_t>(std::max<std::uint64_t>(
        1, std::min<std::uint64_t>(headroom / byte_time_numerator_ - 1,
                                   std::numeric_limits<std::size_t>::max())));
  }
}

std::size_t Impairment::free_space() const {
  return options_.buffer_limit > bytes_.size() ? options_.buffer_limit - bytes_.size() : 0;
}

std::size_t Impairment::push(std::span<const std::uint8_t> bytes, TimePoint now) {
  const std::size_t accepted = std::min(bytes.size(), free_space());
  if (accepted == 0) return 0;
  counters_.bytes_in += accepted;
  if (line_free_ < now) {  // the line was idle: this chunk starts on it right away
    line_free_ = now;
    line_remainder_ = 0;
  }
  Duration delay = options_.latency;
  if (options_.jitter > Duration::zero()) {
    delay += Duration(static_cast<Duration::rep>(
        jitter_random_.up_to(static_cast<std::uint64_t>(options_.jitter.count()))));
  }
  // Jitter smaller than the previous chunk's must not overtake it: hold the chunk back instead.
  const TimePoint first_due = due_time(Run{line_free_ + delay, line_remainder_, 1, 0}, 0);
  if (first_due < last_due_) delay += last_due_ - first_due;

  Run* open = nullptr;  // deque::push_back keeps references to existing elements valid
  Run* last = nullptr;
  for (const std::uint8_t byte : bytes.first(accepted)) {
    if (lose_next_byte()) {
      ++counters_.bytes_lost;
      occupy_line_for_one_byte();
      open = nullptr;
      continue;
    }
    if (open == nullptr || open->count >= max_run_length_) {
      runs_.push_back(Run{line_free_ + delay, line_remainder_, 0, 0});
      open = &runs_.back();
      last = open;
    }
    bytes_.push_back(corrupt(byte));
    ++open->count;
    occupy_line_for_one_byte();
  }
  if (last != nullptr) last_due_ = due_time(*last, last->count - 1);
  return accepted;
}

TimePoint Impairment::next_delivery() const {
  if (runs_.empty()) return TimePoint::max();
  return due_time(runs_.front(), runs_.front().delivered);
}

void Impairment::pop_due(TimePoint now, std::string& out) {
  while (!runs_.empty()) {
    Run& run = runs_.front();
    const std::size_t due = due_count(run, now);
    if (due > run.delivered) {
      const auto fresh = static_cast<std::ptrdiff_t>(due - run.delivered);
      out.append(bytes_.begin(), bytes_.begin() + fresh);
      bytes_.erase(bytes_.begin(), bytes_.begin() + fresh);
      counters_.bytes_out += due - run.delivered;
      run.delivered = due;
    }
    if (run.delivered < run.count) return;
    runs_.pop_front();
  }
}

void Impairment::discard_held(DiscardReason reason, TimePoint now) {
  auto& counter = reason == DiscardReason::cut ? counters_.bytes_dropped_in_cut
                                               : counters_.bytes_dropped_on_disconnect;
  counter += bytes_.size();
  bytes_.clear();
  runs_.clear();
  line_free_ = now;
  line_remainder_ = 0;
  last_due_ = TimePoint::min();
}

TimePoint Impairment::due_time(const Run& run, std::size_t index) const {
  if (options_.bandwidth_bps == 0) return run.base;
  const std::uint64_t numerator = run.line_remainder + (index + 1) * byte_time_numerator_;
  return run.base + Duration(static_cast<Duration::rep>(numerator / options_.bandwidth_bps));
}

std::size_t Impairment::due_count(const Run& run, TimePoint now) const {
  if (now < run.base) return 0;
  if (options_.bandwidth_bps == 0 || due_time(run, run.count - 1) <= now) return run.count;
  // Byte k is due iff (remainder + (k + 1) * numerator) / bps <= elapsed, i.e.
  // (k + 1) * numerator <= (elapsed + 1) * bps - remainder - 1. The last byte is not due yet, so
  // elapsed is below the run's span and the products stay in range (see max_run_length_).
  const auto elapsed = static_cast<std::uint64_t>((now - run.base).count());
  const std::uint64_t limit = (elapsed + 1) * options_.bandwidth_bps - run.line_remainder - 1;
  return std::min<std::size_t>(run.count, static_cast<std::size_t>(limit / byte_time_numerator_));
}

void Impairment::occupy_line_for_one_byte() {
  if (options_.bandwidth_bps == 0) return;
  line_remainder_ += byte_time_numerator_;
  line_free_ += Duration(static_cast<Duration::rep>(line_remainder_ / options_.bandwidth_bps));
  line_remainder_ %= options_.bandwidth_bps;
}

std::uint8_t Impairment::corrupt(std::uint8_t byte) {
  if (options_.bit_error_rate <= 0.0) return byte;
  while (bits_before_next_flip_ < 8) {
    byte = static_cast<std::uint8_t>(byte ^ (1u << bits_before_next_flip_));
    ++counters_.bits_flipped;
    bits_before_next_flip_ = saturating_add(
        bits_before_next_flip_,
        saturating_add(1, bit_error_random_.failures_before_success(options_.bit_error_rate)));
  }
  bits_before_next_flip_ -= 8;
  return byte;
}

bool Impairment::lose_next_byte() {
  if (options_.byte_loss_rate <= 0.0) return false;
  if (bytes_before_next_loss_ > 0) {
    --bytes_before_next_loss_;
    return false;
  }
  bytes_before_next_loss_ = loss_random_.failures_before_success(options_.byte_loss_rate);
  return true;
}

}  // namespace canbridge::emulator
