// libFuzzer target: the serial backbone's peer authentication (backbone/peer_authenticator) on
// arbitrary handshake bytes and arbitrary, tampered, cut and replayed sealed messages. Also
// linked into backbone_auth_tests, which feeds it seeded random inputs (PeerAuthenticatorFuzz.*).
//
// Input: byte 0: bit 0 picks the tag size (16 or 32), bit 1 which end is attacked with the
// handshake bytes; then 1 length byte and that many bytes taken as the attacker's challenge,
// 1 length byte and that many as its proof; then operations [op, arg, ...]:
//   op % 5 == 0: the gateway seals arg % 65 bytes that follow (an honest message, kept);
//             1: the surface opens kept message arg % kept (delivery, late or repeated);
//             2: kept message arg % kept with one byte (next input byte) xored with a non-zero
//                value (the byte after), then opened;
//             3: arg bytes that follow opened as they are (a forgery);
//             4: kept message arg % kept cut to its first (next input byte) bytes, then opened.
//
// Invariants: a handshake fed an attacker's challenge and proof never establishes (nobody can
// produce a proof without the key); open() accepts exactly the kept messages whose counter is
// above the last one accepted, returns them unchanged, and refuses everything else; each open()
// counts once in opened, truncated, bad_tags or replays.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "backbone/peer_authenticator.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

using canbridge::backbone::AuthRole;
using canbridge::backbone::kPreSharedKeySize;
using canbridge::backbone::PeerAuthenticator;
using canbridge::backbone::PeerAuthenticatorOptions;
using canbridge::backbone::PreSharedKey;

using canbridge::fuzz::Input;
using canbridge::fuzz::require;

PeerAuthenticatorOptions options(AuthRole role, std::size_t tag_size, std::uint8_t random_start) {
  std::array<std::uint8_t, kPreSharedKeySize> key{};
  for (std::size_t i = 0; i < key.size(); ++i) key[i] = static_cast<std::uint8_t>(3 * i + 1);
  PeerAuthenticatorOptions o;
  o.role = role;
  o.own_identity = role == AuthRole::gateway ? "gw1" : "surface";
  o.peer_identity = role == AuthRole::gateway ? "surface" : "gw1";
  o.keys = {PreSharedKey(key)};
  o.tag_size = tag_size;
  o.random = [next = random_start](std::span<std::uint8_t> out) mutable {
    for (auto& b : out) b = next++;
    return true;
  };
  return o;
}

struct Kept {
  std::string sealed;
  std::uint64_t counter;
  std::size_t message_size;
};

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  Input in({data, size});
  const std::uint8_t mode = in.byte();
  const std::size_t tag_size = (mode & 1) ? 32 : 16;

  // The handshake against an attacker who has the wire but not the key.
  {
    const AuthRole attacked = (mode & 2) ? AuthRole::surface : AuthRole::gateway;
    PeerAuthenticator victim(options(attacked, tag_size, 1));
    const auto challenge = in.take(in.byte());
    const auto proof = in.take(in.byte());
    require(victim.make_challenge().has_value(), "make_challenge failed");
    const bool responded = victim.respond(challenge).has_value();
    require(!victim.verify(proof), "an attacker's proof was accepted");
    require(victim.state() == PeerAuthenticator::State::failed, "a failed handshake did not stick");
    // A respond() that failed makes verify() a call out of order: counted a second time.
    const auto& c = victim.counters();
    require(c.malformed_challenges + c.parameter_mismatches + c.unknown_keys + c.bad_proofs +
                    c.out_of_order ==
                (responded ? 1u : 2u),
            "a failed handshake step counted other than once");
    require(responded == (c.bad_proofs == 1), "verify failed for another reason after respond");
  }

  PeerAuthenticator gateway(options(AuthRole::gateway, tag_size, 1));
  PeerAuthenticator surface(options(AuthRole::surface, tag_size, 101));
  const auto gc = gateway.make_challenge();
  const auto sc = surface.make_challenge();
  const auto sp = surface.respond(*gc);
  const auto gp = gateway.respond(*sc);
  require(gateway.verify(*sp) && surface.verify(*gp), "honest handshake failed");

  std::vector<Kept> kept;
  std::uint64_t next_counter = 1;
  std::uint64_t last_accepted = 0;
  std::uint64_t opens = 0;
  // raw: bytes the input chose outright. The keys are the same in every run (fixed seeds), so
  // such bytes can be a message the gateway sealed in another run (a corpus entry carries one):
  // authentic, and then it must only be newer than the last one accepted.
  const auto open = [&](std::span<const std::uint8_t> sealed, bool raw = false) {
    ++opens;
    const auto message = surface.open(sealed);
    if (raw && message) {
      std::uint64_t counter = 0;
      for (std::size_t i = 0; i < 4; ++i) counter = counter << 8 | sealed[i];
      require(counter > last_accepted, "a raw message older than the last one opened");
      last_accepted = counter;
      return;
    }
    // The model: the kept message with these exact bytes and a counter above the last one.
    const Kept* match = nullptr;
    for (const Kept& k : kept) {
      if (bytes(k.sealed).size() == sealed.size() &&
          std::equal(sealed.begin(), sealed.end(), bytes(k.sealed).begin())) {
        match = &k;
      }
    }
    const bool should_open = match != nullptr && match->counter > last_accepted;
    require(message.has_value() == should_open, "open() disagrees with the model");
    if (message) {
      require(message->size() == match->message_size &&
                  std::equal(message->begin(), message->end(), sealed.begin() + 4),
              "opened message is not the sealed one");
      last_accepted = match->counter;
    }
  };

  while (!in.empty() && kept.size() < 256) {
    const std::uint8_t op = in.byte() % 5;
    const std::uint8_t arg = in.byte();
    if (op == 0 || kept.empty()) {
      const auto message = in.take(arg % 65);
      std::string sealed;
      require(gateway.seal(message, sealed), "seal failed");
      require(sealed.size() == message.size() + gateway.seal_overhead(), "sealed size");
      kept.push_back({std::move(sealed), next_counter++, message.size()});
    } else if (op == 1) {
      open(bytes(kept[arg % kept.size()].sealed));
    } else if (op == 2) {
      std::string bad = kept[arg % kept.size()].sealed;
      const std::size_t at = in.byte() % bad.size();
      bad[at] = static_cast<char>(bad[at] ^ (in.byte() | 1));
      open(bytes(bad));
    } else if (op == 3) {
      open(in.take(arg), true);
    } else {
      const std::string& k = kept[arg % kept.size()].sealed;
      open(bytes(k).first(in.byte() % k.size()));
    }
  }
  const auto& c = surface.counters();
  require(c.opened + c.truncated + c.bad_tags + c.replays == opens,
          "open() counted other than once");
  return 0;
}
