// The serial backbone's authentication (docs/security.md, "Serial lines"): a mutual
// challenge-response proving both ends hold the gateway's pre-shared key, then a MAC with a
// per-direction counter on every message, so forged, tampered, replayed and reordered messages
// are refused. A pure core: bytes in, bytes out; the session carries them.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "backbone/pre_shared_keys.hpp"

namespace canbridge::backbone {

// The gateway opens the handshake and picks the key; the surface answers with the key it names.
enum class AuthRole : std::uint8_t { gateway = 1, surface = 2 };

inline constexpr std::uint8_t kAuthVersion = 1;
inline constexpr std::size_t kAuthNonceSize = 32;
inline constexpr std::size_t kKeyIdSize = 8;
// version (1) | tag size (1) | key id (8) | nonce (32)
inline constexpr std::size_t kAuthChallengeSize = 2 + kKeyIdSize + kAuthNonceSize;
inline constexpr std::size_t kAuthProofSize = 32;
// Low 32 bits of the message counter, big endian, in front of every sealed message.
inline constexpr std::size_t kSealCounterSize = 4;

using AuthChallenge = std::array<std::uint8_t, kAuthChallengeSize>;
using AuthProof = std::array<std::uint8_t, kAuthProofSize>;
using KeyId = std::array<std::uint8_t, kKeyIdSize>;

// The full counter of a sealed message from the low 32 bits on the wire: the smallest counter
// above `last_accepted` with those low bits. Lost messages leave gaps, which is fine; the tag
// covers all 64 bits, so a wrong guess (an old message from an earlier epoch) fails the tag.
std::uint64_t rebuild_seal_counter(std::uint64_t last_accepted, std::uint32_t low) noexcept;

// Fills its argument with unpredictable bytes; false when it cannot.
using RandomSource = std::function<bool(std::span<std::uint8_t>)>;
// OpenSSL's RAND_bytes.
RandomSource system_random();

// Names a key on the wire without revealing it: HMAC-SHA-256(key, "canbridge key id v1"),
// first 8 bytes.
KeyId key_id(const PreSharedKey& key);

struct PeerAuthenticatorOptions {
  AuthRole role = AuthRole::gateway;
  std::string own_identity;   // e.g. the gateway's name, or the surface's
  std::string peer_identity;  // the other end's, from the configuration
  // The gateway proves with keys[0]; the surface accepts any of them, the one the gateway's
  // challenge names (two during rotation). At least one.
  std::vector<PreSharedKey> keys;
  std::size_t tag_size = 16;  // 16 or 32 bytes; both ends must agree
  RandomSource random;        // empty: system_random()
};

// Monotonic. Every handshake call that fails counts once in the first group, every open() that
// fails once in the second.
struct AuthCounters {
  std::uint64_t malformed_challenges = 0;  // wrong size or version, or our own nonce
  std::uint64_t parameter_mismatches = 0;  // the peer uses another tag size
  std::uint64_t unknown_keys = 0;          // surface: the gateway's key id is none of ours
  std::uint64_t bad_proofs = 0;            // wrong key, reflected or forged proof
  std::uint64_t out_of_order = 0;          // a handshake call in the wrong state
  std::uint64_t random_failures = 0;
  std::uint64_t sealed = 0;
  std::uint64_t opened = 0;
  std::uint64_t truncated = 0;        // shorter than counter and tag
  std::uint64_t bad_tags = 0;         // tampered, forged, truncated or extended
  std::uint64_t replays = 0;          // authentic, but its counter is not above the last one
  std::uint64_t not_established = 0;  // seal/open before the handshake completed
};

class PeerAuthenticator {
 public:
  // idle -make_challenge-> challenged -respond-> responded -verify-> established; any failed
  // handshake step -> failed, for good: a new attempt needs a new authenticator (new nonces).
  enum class State { idle, challenged, responded, established, failed };

  // Throws std::invalid_argument for options that can never work (no key, tag size, identity
  // longer than 255 bytes): a configuration error, found at startup.
  explicit PeerAuthenticator(PeerAuthenticatorOptions options);
  ~PeerAuthenticator();
  PeerAuthenticator(const PeerAuthenticator&) = delete;
  PeerAuthenticator& operator=(const PeerAuthenticator&) = delete;

  // This end's challenge, to send to the peer. Nullopt if the random source fails.
  std::optional<AuthChallenge> make_challenge();
  // Takes the peer's challenge (after make_challenge) and returns this end's proof.
  std::optional<AuthProof> respond(std::span<const std::uint8_t> peer_challenge);
  // Checks the peer's proof (after respond); true establishes the session keys.
  bool verify(std::span<const std::uint8_t> peer_proof);

  // Appends counter (4) | message | tag (tag_size) to `out`. False before the session is
  // established (nothing appended).
  bool seal(std::span<const std::uint8_t> message, std::string& out);
  // The message inside `sealed` (a view into it) when its tag is right and its counter is above
  // every counter accepted before; otherwise nullopt, counted by reason.
  std::optional<std::span<const std::uint8_t>> open(std::span<const std::uint8_t> sealed);

  State state() const { return state_; }
  AuthRole role() const { return role_; }
  // The other end's configured identity: who it has proven to be once established.
  const std::string& peer_identity() const {
    return role_ == AuthRole::gateway ? surface_identity_ : gateway_identity_;
  }
  const AuthCounters& counters() const { return counters_; }
  std::size_t seal_overhead() const { return kSealCounterSize + tag_size_; }

 private:
  struct Mac;

  bool fail(std::uint64_t& reason);
  std::vector<std::uint8_t> transcript(std::string_view purpose) const;
  void tag(Mac& mac, std::uint64_t counter, std::span<const std::uint8_t> message,
           std::span<std::uint8_t, kAuthProofSize> out) const;

  AuthRole role_;
  std::string gateway_identity_;
  std::string surface_identity_;
  std::vector<PreSharedKey> keys_;
  std::size_t tag_size_;
  RandomSource random_;

  State state_ = State::idle;
  AuthChallenge own_challenge_{};
  AuthChallenge peer_challenge_{};
  std::optional<PreSharedKey> session_psk_;  // the key both ends prove with
  std::unique_ptr<Mac> send_mac_;
  std::unique_ptr<Mac> receive_mac_;
  std::uint64_t last_sent_ = 0;      // counter of the last sealed message; the first is 1
  std::uint64_t last_received_ = 0;  // highest counter opened
  AuthCounters counters_;
};

}  // namespace canbridge::backbone
