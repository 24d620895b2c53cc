#include "backbone/peer_authenticator.hpp"

#include <gtest/gtest.h>
#include <openssl/core_names.h>
#include <openssl/evp.h>
#include <openssl/kdf.h>
#include <openssl/params.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <numeric>
#include <random>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace canbridge::backbone {
namespace {

using Bytes = std::vector<std::uint8_t>;

PreSharedKey test_key(std::uint8_t seed) {
  std::array<std::uint8_t, kPreSharedKeySize> b{};
  std::iota(b.begin(), b.end(), seed);
  return PreSharedKey(b);
}

// Deterministic "random" bytes so a test can replay a session; each source its own stream.
RandomSource counting_random(std::uint8_t start) {
  return [next = start](std::span<std::uint8_t> out) mutable {
    for (auto& b : out) b = next++;
    return true;
  };
}

PeerAuthenticatorOptions options(AuthRole role, std::vector<PreSharedKey> keys,
                                 std::uint8_t random_start, std::size_t tag_size = 16) {
  PeerAuthenticatorOptions o;
  o.role = role;
  o.own_identity = role == AuthRole::gateway ? "gw1" : "surface";
  o.peer_identity = role == AuthRole::gateway ? "surface" : "gw1";
  o.keys = std::move(keys);
  o.tag_size = tag_size;
  o.random = counting_random(random_start);
  return o;
}

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

// Runs the three-message handshake of docs/security.md; true when both ends are established.
bool handshake(PeerAuthenticator& gateway, PeerAuthenticator& surface) {
  const auto gateway_challenge = gateway.make_challenge();
  const auto surface_challenge = surface.make_challenge();
  if (!gateway_challenge || !surface_challenge) return false;
  const auto surface_proof = surface.respond(*gateway_challenge);
  if (!surface_proof) return false;
  const auto gateway_proof = gateway.respond(*surface_challenge);
  if (!gateway_proof) return false;
  const bool gateway_ok = gateway.verify(*surface_proof);
  const bool surface_ok = surface.verify(*gateway_proof);
  return gateway_ok && surface_ok;
}

std::string seal(PeerAuthenticator& a, const Bytes& message) {
  std::string out;
  EXPECT_TRUE(a.seal(message, out));
  return out;
}

Bytes message64(std::uint8_t seed) {
  Bytes m(64);
  std::iota(m.begin(), m.end(), seed);
  return m;
}

struct Pair {
  PeerAuthenticator gateway;
  PeerAuthenticator surface;
  explicit Pair(std::size_t tag_size = 16, std::uint8_t g = 1, std::uint8_t s = 101)
      : gateway(options(AuthRole::gateway, {test_key(7)}, g, tag_size)),
        surface(options(AuthRole::surface, {test_key(7)}, s, tag_size)) {
    EXPECT_TRUE(handshake(gateway, surface));
  }
};

TEST(PeerAuthenticatorHandshake, SameKeyAuthenticatesBothEnds) {
  Pair p;
  EXPECT_EQ(p.gateway.state(), PeerAuthenticator::State::established);
  EXPECT_EQ(p.surface.state(), PeerAuthenticator::State::established);
  const Bytes m = message64(3);
  const std::string sealed = seal(p.gateway, m);
  EXPECT_EQ(sealed.size(), m.size() + p.gateway.seal_overhead());
  const auto opened = p.surface.open(bytes(sealed));
  ASSERT_TRUE(opened);
  EXPECT_EQ(Bytes(opened->begin(), opened->end()), m);
  const std::string back = seal(p.surface, m);
  ASSERT_TRUE(p.gateway.open(bytes(back)));
}

TEST(PeerAuthenticatorHandshake, WrongKeyFailsBothWays) {
  // The surface knows a different key under the id the gateway names: both proofs are wrong.
  PeerAuthenticator gateway(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator surface(options(AuthRole::surface, {test_key(8)}, 101));
  const auto gc = gateway.make_challenge();
  const auto sc = surface.make_challenge();
  AuthChallenge gc_for_surface = *gc;
  const KeyId surface_id = key_id(test_key(8));
  std::copy(surface_id.begin(), surface_id.end(), gc_for_surface.begin() + 2);
  const auto sp = surface.respond(gc_for_surface);
  const auto gp = gateway.respond(*sc);
  ASSERT_TRUE(sp && gp);
  EXPECT_FALSE(gateway.verify(*sp));
  EXPECT_FALSE(surface.verify(*gp));
  EXPECT_EQ(gateway.counters().bad_proofs, 1u);
  EXPECT_EQ(surface.counters().bad_proofs, 1u);
  EXPECT_EQ(gateway.state(), PeerAuthenticator::State::failed);
  std::string out;
  EXPECT_FALSE(gateway.seal(message64(0), out));
  EXPECT_TRUE(out.empty());
}

TEST(PeerAuthenticatorHandshake, KeyUnknownToTheSurfaceIsRefused) {
  PeerAuthenticator gateway(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator surface(options(AuthRole::surface, {test_key(8)}, 101));
  EXPECT_FALSE(handshake(gateway, surface));
  EXPECT_EQ(surface.counters().unknown_keys, 1u);
}

TEST(PeerAuthenticatorHandshake, SurfaceAcceptsEitherKeyDuringRotation) {
  for (const std::uint8_t gateway_key : {7, 9}) {
    PeerAuthenticator gateway(options(AuthRole::gateway, {test_key(gateway_key)}, 1));
    PeerAuthenticator surface(options(AuthRole::surface, {test_key(7), test_key(9)}, 101));
    ASSERT_TRUE(handshake(gateway, surface)) << int(gateway_key);
    ASSERT_TRUE(surface.open(bytes(seal(gateway, message64(1)))));
  }
}

TEST(PeerAuthenticatorHandshake, ReflectedProofFails) {
  // A rogue surface without the key sends the gateway's own proof back.
  PeerAuthenticator gateway(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator rogue(options(AuthRole::surface, {test_key(7)}, 101));
  const auto gc = gateway.make_challenge();
  const auto rc = rogue.make_challenge();
  ASSERT_TRUE(rogue.respond(*gc));
  const auto gateway_proof = gateway.respond(*rc);
  ASSERT_TRUE(gateway_proof);
  EXPECT_FALSE(gateway.verify(*gateway_proof));
  EXPECT_EQ(gateway.counters().bad_proofs, 1u);
  // And the surface's proof sent back to the surface.
  PeerAuthenticator g2(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator s2(options(AuthRole::surface, {test_key(7)}, 101));
  const auto gc2 = g2.make_challenge();
  ASSERT_TRUE(s2.make_challenge());
  const auto surface_proof = s2.respond(*gc2);
  EXPECT_FALSE(s2.verify(*surface_proof));
}

TEST(PeerAuthenticatorHandshake, ReflectedChallengeIsRefused) {
  PeerAuthenticator surface(options(AuthRole::surface, {test_key(7)}, 101));
  const auto sc = surface.make_challenge();
  EXPECT_FALSE(surface.respond(*sc));
  EXPECT_EQ(surface.counters().malformed_challenges, 1u);
}

TEST(PeerAuthenticatorHandshake, ProofFromAnotherSessionFails) {
  // A recorded gateway proof replayed against a new surface nonce.
  Pair recorded;
  PeerAuthenticator g1(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator s1(options(AuthRole::surface, {test_key(7)}, 101));
  const auto gc = g1.make_challenge();
  const auto sc1 = s1.make_challenge();
  ASSERT_TRUE(s1.respond(*gc));
  const auto old_proof = g1.respond(*sc1);
  PeerAuthenticator s2(options(AuthRole::surface, {test_key(7)}, 201));
  ASSERT_TRUE(s2.make_challenge());
  ASSERT_TRUE(s2.respond(*gc));
  EXPECT_FALSE(s2.verify(*old_proof));
}

TEST(PeerAuthenticatorHandshake, MalformedInputsFailAndCount) {
  PeerAuthenticator a(options(AuthRole::surface, {test_key(7)}, 101));
  EXPECT_FALSE(a.respond(Bytes(kAuthChallengeSize, 1)));  // before make_challenge
  EXPECT_EQ(a.counters().out_of_order, 1u);
  PeerAuthenticator b(options(AuthRole::surface, {test_key(7)}, 101));
  ASSERT_TRUE(b.make_challenge());
  EXPECT_FALSE(b.respond(Bytes(kAuthChallengeSize - 1, 1)));
  EXPECT_EQ(b.counters().malformed_challenges, 1u);
  PeerAuthenticator c(options(AuthRole::surface, {test_key(7)}, 101));
  PeerAuthenticator g(options(AuthRole::gateway, {test_key(7)}, 1, 32));
  ASSERT_TRUE(c.make_challenge());
  EXPECT_FALSE(c.respond(*g.make_challenge()));
  EXPECT_EQ(c.counters().parameter_mismatches, 1u);
  Pair p;
  EXPECT_FALSE(p.gateway.verify(Bytes(kAuthProofSize)));  // already established
}

TEST(PeerAuthenticatorHandshake, TruncatedProofFails) {
  PeerAuthenticator gateway(options(AuthRole::gateway, {test_key(7)}, 1));
  PeerAuthenticator surface(options(AuthRole::surface, {test_key(7)}, 101));
  const auto gc = gateway.make_challenge();
  const auto sc = surface.make_challenge();
  const auto sp = surface.respond(*gc);
  ASSERT_TRUE(gateway.respond(*sc));
  EXPECT_FALSE(gateway.verify(std::span(*sp).first(kAuthProofSize - 1)));
  EXPECT_EQ(gateway.counters().bad_proofs, 1u);
}

TEST(PeerAuthenticatorMessages, ReplayIsRejectedAndCounted) {
  Pair p;
  const std::string first = seal(p.gateway, message64(1));
  ASSERT_TRUE(p.surface.open(bytes(first)));
  EXPECT_FALSE(p.surface.open(bytes(first)));
  EXPECT_EQ(p.surface.counters().replays, 1u);
  EXPECT_EQ(p.surface.counters().bad_tags, 0u);
}

TEST(PeerAuthenticatorMessages, ReorderedIsRejectedButGapsAreAccepted) {
  Pair p;
  const std::string m1 = seal(p.gateway, message64(1));
  const std::string m2 = seal(p.gateway, message64(2));
  const std::string m3 = seal(p.gateway, message64(3));
  ASSERT_TRUE(p.surface.open(bytes(m2)));   // m1 lost on the line: fine
  EXPECT_FALSE(p.surface.open(bytes(m1)));  // arrives late: refused
  EXPECT_EQ(p.surface.counters().replays, 1u);
  EXPECT_TRUE(p.surface.open(bytes(m3)));
}

TEST(PeerAuthenticatorMessages, EveryFlippedBitPositionIsRejected) {
  for (const std::size_t tag_size : {16u, 32u}) {
    Pair p(tag_size);
    const std::string good = seal(p.gateway, message64(5));
    std::uint64_t expected_rejects = 0;
    for (std::size_t i = 0; i < good.size(); ++i) {
      for (const std::uint8_t flip : {0x01, 0x80, 0xFF}) {
        std::string bad = good;
        bad[i] = static_cast<char>(bad[i] ^ flip);
        EXPECT_FALSE(p.surface.open(bytes(bad))) << "byte " << i << " flip " << int(flip);
        ++expected_rejects;
      }
    }
    EXPECT_EQ(p.surface.counters().bad_tags + p.surface.counters().replays, expected_rejects);
    EXPECT_EQ(p.surface.counters().opened, 0u);
    EXPECT_TRUE(p.surface.open(bytes(good)));  // the untouched one still opens
  }
}

TEST(PeerAuthenticatorMessages, TruncatedAndExtendedAreRejected) {
  Pair p;
  const std::string good = seal(p.gateway, message64(5));
  for (std::size_t n = 0; n < good.size(); ++n) {
    EXPECT_FALSE(p.surface.open(bytes(good.substr(0, n)))) << n;
    EXPECT_FALSE(p.surface.open(bytes(good.substr(good.size() - n)))) << n;  // head cut off
  }
  EXPECT_EQ(p.surface.counters().truncated, 2 * (kSealCounterSize + 16));
  EXPECT_FALSE(p.surface.open(bytes(good + '\0')));
  EXPECT_FALSE(p.surface.open(bytes(good + good)));
  EXPECT_EQ(p.surface.counters().opened, 0u);
  EXPECT_GT(p.surface.counters().bad_tags, 0u);
  EXPECT_TRUE(p.surface.open(bytes(good)));
}

TEST(PeerAuthenticatorMessages, EmptyMessageIsSealedAndOpened) {
  Pair p;
  const auto opened = p.surface.open(bytes(seal(p.gateway, {})));
  ASSERT_TRUE(opened);
  EXPECT_TRUE(opened->empty());
}

TEST(PeerAuthenticatorMessages, OtherSessionsAndDirectionsCannotOpen) {
  Pair a(16, 1, 101);
  Pair b(16, 51, 151);  // same key, other nonces
  const std::string m = seal(a.gateway, message64(1));
  EXPECT_FALSE(b.surface.open(bytes(m)));
  EXPECT_FALSE(a.gateway.open(bytes(m)));  // reflected to its sender
  EXPECT_EQ(b.surface.counters().bad_tags, 1u);
  EXPECT_TRUE(a.surface.open(bytes(m)));
}

TEST(PeerAuthenticatorMessages, SealAndOpenBeforeTheHandshakeAreRefused) {
  PeerAuthenticator a(options(AuthRole::gateway, {test_key(7)}, 1));
  std::string out;
  EXPECT_FALSE(a.seal(message64(1), out));
  EXPECT_FALSE(a.open(Bytes(100)));
  EXPECT_EQ(a.counters().not_established, 2u);
}

TEST(PeerAuthenticatorMessages, LateMessageCountsAsReplayNotForgery) {
  Pair p;
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(p.surface.open(bytes(seal(p.gateway, message64(1)))));
  const std::string early = seal(p.gateway, message64(9));
  ASSERT_TRUE(p.surface.open(bytes(seal(p.gateway, message64(2)))));
  EXPECT_FALSE(p.surface.open(bytes(early)));
  EXPECT_EQ(p.surface.counters().replays, 1u);
  EXPECT_EQ(p.surface.counters().bad_tags, 0u);
}

TEST(SealCounter, RebuiltAcrossThe32BitBoundary) {
  constexpr std::uint64_t k2_32 = std::uint64_t{1} << 32;
  EXPECT_EQ(rebuild_seal_counter(0, 1), 1u);
  EXPECT_EQ(rebuild_seal_counter(1, 5), 5u);         // a gap
  EXPECT_EQ(rebuild_seal_counter(5, 5), k2_32 + 5);  // not above 5 in this epoch: the next one
  EXPECT_EQ(rebuild_seal_counter(5, 3), k2_32 + 3);
  EXPECT_EQ(rebuild_seal_counter(k2_32 - 1, 0), k2_32);
  EXPECT_EQ(rebuild_seal_counter(k2_32 - 2, 0xFFFFFFFFu), k2_32 - 1);
  EXPECT_EQ(rebuild_seal_counter(3 * k2_32 + 7, 8), 3 * k2_32 + 8);
  EXPECT_EQ(rebuild_seal_counter(3 * k2_32 + 7, 2), 4 * k2_32 + 2);
}

// The protocol as docs/security.md writes it, recomputed with OpenSSL's one-shot functions:
// a change of layout or labels in the code fails here and must be made in the document too.
Bytes hmac(std::span<const std::uint8_t> key, std::span<const std::uint8_t> data) {
  Bytes out(32);
  std::size_t len = 0;
  EXPECT_NE(EVP_Q_mac(nullptr, "HMAC", nullptr, "SHA256", nullptr, key.data(), key.size(),
                      data.data(), data.size(), out.data(), out.size(), &len),
            nullptr);
  return out;
}

Bytes transcript(const std::string& purpose, const AuthChallenge& g, const AuthChallenge& s) {
  Bytes t;
  const auto add = [&t](std::span<const std::uint8_t> b) { t.insert(t.end(), b.begin(), b.end()); };
  add(bytes("canbridge serial auth v1"));
  t.push_back(0);
  add(bytes(purpose));
  t.push_back(0);
  t.push_back(3);
  add(bytes("gw1"));
  t.push_back(7);
  add(bytes("surface"));
  add(g);
  add(s);
  return t;
}

TEST(PeerAuthenticatorSpec, WireFormatMatchesTheDocument) {
  const PreSharedKey k = test_key(7);
  PeerAuthenticator gateway(options(AuthRole::gateway, {k}, 1));
  PeerAuthenticator surface(options(AuthRole::surface, {k}, 101));
  const auto gc = *gateway.make_challenge();
  const auto sc = *surface.make_challenge();
  EXPECT_EQ(gc[0], 1);
  EXPECT_EQ(gc[1], 16);
  const Bytes id = hmac(k.bytes(), bytes("canbridge key id v1"));
  EXPECT_TRUE(std::equal(gc.begin() + 2, gc.begin() + 10, id.begin()));
  EXPECT_TRUE(std::all_of(sc.begin() + 2, sc.begin() + 10, [](auto b) { return b == 0; }));
  const auto sp = *surface.respond(gc);
  const auto gp = *gateway.respond(sc);
  EXPECT_EQ(Bytes(sp.begin(), sp.end()), hmac(k.bytes(), transcript("surface proof", gc, sc)));
  EXPECT_EQ(Bytes(gp.begin(), gp.end()), hmac(k.bytes(), transcript("gateway proof", gc, sc)));
  ASSERT_TRUE(gateway.verify(sp));

  // Session key gateway -> surface: HKDF-SHA-256(psk, salt = both nonces, info = transcript).
  Bytes salt(gc.begin() + 10, gc.end());
  salt.insert(salt.end(), sc.begin() + 10, sc.end());
  Bytes info = transcript("gateway to surface", gc, sc);
  Bytes ikm(k.bytes().begin(), k.bytes().end());
  EVP_KDF* kdf = EVP_KDF_fetch(nullptr, "HKDF", nullptr);
  EVP_KDF_CTX* ctx = EVP_KDF_CTX_new(kdf);
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {
      OSSL_PARAM_construct_utf8_string(OSSL_KDF_PARAM_DIGEST, digest, 0),
      OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_KEY, ikm.data(), ikm.size()),
      OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_SALT, salt.data(), salt.size()),
      OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_INFO, info.data(), info.size()),
      OSSL_PARAM_END};
  Bytes session_key(32);
  ASSERT_EQ(EVP_KDF_derive(ctx, session_key.data(), session_key.size(), params), 1);
  EVP_KDF_CTX_free(ctx);
  EVP_KDF_free(kdf);

  const Bytes m = message64(0);
  std::string sealed;
  ASSERT_TRUE(gateway.seal(m, sealed));
  ASSERT_TRUE(gateway.seal(m, sealed));  // the second message, counter 2
  const auto second = bytes(sealed).subspan(sealed.size() / 2);
  EXPECT_EQ(Bytes(second.begin(), second.begin() + 4), (Bytes{0, 0, 0, 2}));
  EXPECT_EQ(Bytes(second.begin() + 4, second.begin() + 4 + 64), m);
  Bytes mac_input{0, 0, 0, 0, 0, 0, 0, 2};
  mac_input.insert(mac_input.end(), m.begin(), m.end());
  const Bytes full = hmac(session_key, mac_input);
  EXPECT_EQ(Bytes(second.end() - 16, second.end()), Bytes(full.begin(), full.begin() + 16));
}

// The fuzz target's model and invariants (tests/fuzz/peer_authenticator_fuzz.cpp) on seeded
// random inputs: mostly honest seals and deliveries, with tampering, cuts, forgeries and replays.
TEST(PeerAuthenticatorFuzz, RandomInputsMatchTheModel) {
  for (std::uint32_t seed = 1; seed <= 300; ++seed) {
    std::mt19937 rng(seed);
    Bytes input(3 + rng() % 120);
    for (auto& b : input) b = static_cast<std::uint8_t>(rng());
    input[1] = static_cast<std::uint8_t>(seed % 3 == 0 ? kAuthChallengeSize : input[1] % 8);
    EXPECT_EQ(LLVMFuzzerTestOneInput(input.data(), input.size()), 0);
  }
}

}  // namespace
}  // namespace canbridge::backbone
