// What the serial backbone's message authentication costs per message: seal and open of a
// 64-byte message (about one FrameBatch of a few CAN frames), and one whole handshake, in ns on
// this host. A measurement, not a test (bench/README.md, peer_auth_bench).
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "backbone/peer_authenticator.hpp"

namespace {

using canbridge::backbone::AuthRole;
using canbridge::backbone::PeerAuthenticator;
using canbridge::backbone::PeerAuthenticatorOptions;
using canbridge::backbone::PreSharedKey;
using Clock = std::chrono::steady_clock;

PeerAuthenticatorOptions options(AuthRole role, const PreSharedKey& key, std::size_t tag_size) {
  PeerAuthenticatorOptions o;
  o.role = role;
  o.own_identity = role == AuthRole::gateway ? "gw1" : "surface";
  o.peer_identity = role == AuthRole::gateway ? "surface" : "gw1";
  o.keys = {key};
  o.tag_size = tag_size;
  return o;
}

bool handshake(PeerAuthenticator& g, PeerAuthenticator& s) {
  const auto gc = g.make_challenge();
  const auto sc = s.make_challenge();
  const auto sp = s.respond(*gc);
  const auto gp = g.respond(*sc);
  return sp && gp && g.verify(*sp) && s.verify(*gp);
}

double ns_per(Clock::duration d, long n) {
  return std::chrono::duration<double, std::nano>(d).count() / static_cast<double>(n);
}

}  // namespace

int main(int argc, char** argv) {
  const long rounds = argc > 1 ? std::atol(argv[1]) : 200000;
  std::array<std::uint8_t, 32> key_bytes{};
  for (std::size_t i = 0; i < key_bytes.size(); ++i) key_bytes[i] = static_cast<std::uint8_t>(i);
  const PreSharedKey key(key_bytes);
  const std::vector<std::uint8_t> message(64, 0x5A);

  // The best of several batches: on a shared host the minimum is the cost, the rest is waiting.
  constexpr int kBatches = 20;
  const long per_batch = std::max(1L, rounds / kBatches);
  for (const std::size_t tag_size : {16u, 32u}) {
    PeerAuthenticator g(options(AuthRole::gateway, key, tag_size));
    PeerAuthenticator s(options(AuthRole::surface, key, tag_size));
    if (!handshake(g, s)) return 1;
    std::vector<std::string> sealed(static_cast<std::size_t>(per_batch));
    for (auto& out : sealed) out.reserve(64 + 64);
    double best_seal = 1e18;
    double best_open = 1e18;
    for (int batch = 0; batch < kBatches; ++batch) {
      const auto t0 = Clock::now();
      for (auto& out : sealed) {
        out.clear();
        g.seal(message, out);
      }
      const auto t1 = Clock::now();
      std::size_t opened = 0;
      for (const auto& in : sealed) {
        opened += s.open({reinterpret_cast<const std::uint8_t*>(in.data()), in.size()}).has_value();
      }
      const auto t2 = Clock::now();
      if (opened != sealed.size()) return 1;
      best_seal = std::min(best_seal, ns_per(t1 - t0, per_batch));
      best_open = std::min(best_open, ns_per(t2 - t1, per_batch));
    }
    std::printf(
        "tag %2zu B: seal %5.0f ns, open %5.0f ns per 64-byte message (+%zu B on the wire;"
        " best of %d batches of %ld)\n",
        tag_size, best_seal, best_open, g.seal_overhead(), kBatches, per_batch);
  }

  const long handshakes = std::max(1L, rounds / 200);
  const auto t0 = Clock::now();
  for (long i = 0; i < handshakes; ++i) {
    PeerAuthenticator g(options(AuthRole::gateway, key, 16));
    PeerAuthenticator s(options(AuthRole::surface, key, 16));
    if (!handshake(g, s)) return 1;
  }
  std::printf("handshake (both ends, in one process): %.1f us\n",
              ns_per(Clock::now() - t0, handshakes) / 1000.0);
  return 0;
}
