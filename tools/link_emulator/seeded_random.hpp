// Deterministic random draws for the link emulator: one seed gives the same draws everywhere.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

namespace canbridge::emulator {

// SplitMix64 finaliser: spreads nearby seeds (1, 2, 3, ...) over the whole state space, so the
// streams derived from one user seed are unrelated.
constexpr std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// The seed of one independent stream (a direction, the cut schedule) of a user seed.
constexpr std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t stream) {
  return splitmix64(splitmix64(seed) ^ stream);
}

// std::mt19937_64's output is fixed by the standard, unlike the std distributions, so the
// conversions to doubles and ranges are done here to keep runs reproducible across libraries.
class SeededRandom {
 public:
  explicit SeededRandom(std::uint64_t seed) : engine_(splitmix64(seed)) {}

  // Uniform in (0, 1]: never 0, so its logarithm is finite.
  double unit() { return static_cast<double>((engine_() >> 11) + 1) * 0x1.0p-53; }

  // Uniform in [0, bound].
  std::uint64_t up_to(std::uint64_t bound) {
    if (bound == 0) return 0;
    const double scaled = std::floor((1.0 - unit()) * (static_cast<double>(bound) + 1.0));
    const auto value = static_cast<std::uint64_t>(scaled);
    return value > bound ? bound : value;
  }

  // How many independent trials with success probability p fail before the next success
  // (geometric on 0, 1, 2, ...): one draw replaces a draw per trial, which matters at a bit error
  // rate of 1e-4 and a draw per bit. Saturates at the maximum for p <= 0.
  std::uint64_t failures_before_success(double p) {
    constexpr auto kNever = std::numeric_limits<std::uint64_t>::max();
    if (p >= 1.0) return 0;
    if (p <= 0.0) return kNever;
    const double failures = std::floor(std::log(unit()) / std::log1p(-p));
    if (failures >= 1.8e19) return kNever;
    return static_cast<std::uint64_t>(failures);
  }

 private:
  std::mt19937_64 engine_;
};

}  // namespace canbridge::emulator
