#include "backbone/peer_authenticator.hpp"

#include <openssl/core_names.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/kdf.h>
#include <openssl/params.h>
#include <openssl/rand.h>

#include <algorithm>
#include <stdexcept>
#include <string_view>

namespace canbridge::backbone {

namespace {

constexpr std::string_view kTranscriptLabel = "canbridge serial auth v1";
constexpr std::string_view kKeyIdLabel = "canbridge key id v1";
constexpr std::size_t kVersionOffset = 0;
constexpr std::size_t kTagSizeOffset = 1;
constexpr std::size_t kKeyIdOffset = 2;
constexpr std::size_t kNonceOffset = kKeyIdOffset + kKeyIdSize;
constexpr std::uint64_t kLow32 = 0xFFFFFFFFu;

std::span<const std::uint8_t> as_bytes(std::string_view s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

struct MacFreer {
  void operator()(EVP_MAC* m) const { EVP_MAC_free(m); }
  void operator()(EVP_MAC_CTX* c) const { EVP_MAC_CTX_free(c); }
  void operator()(EVP_KDF* k) const { EVP_KDF_free(k); }
  void operator()(EVP_KDF_CTX* c) const { EVP_KDF_CTX_free(c); }
};

[[noreturn]] void crypto_failure(const char* what) {
  // Only when OpenSSL itself is broken (no HMAC or HKDF in the default provider, no memory).
  throw std::runtime_error(std::string("libcrypto: ") + what + " failed");
}

// HMAC-SHA-256 under one key, keyed once and re-initialised per message: keying and fetching
// the algorithm cost more than hashing a 64-byte message. (A hand-made HMAC from copied SHA-256
// states measured 270 against 330 ns per 64-byte seal; not worth leaving OpenSSL's HMAC.)
class HmacSha256 {
 public:
  explicit HmacSha256(std::span<const std::uint8_t> key) {
    std::unique_ptr<EVP_MAC, MacFreer> hmac(EVP_MAC_fetch(nullptr, "HMAC", nullptr));
    if (!hmac) crypto_failure("EVP_MAC_fetch(HMAC)");
    ctx_.reset(EVP_MAC_CTX_new(hmac.get()));
    if (!ctx_) crypto_failure("EVP_MAC_CTX_new");
    char digest[] = "SHA256";
    const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string(OSSL_MAC_PARAM_DIGEST, digest, 0),
                                 OSSL_PARAM_END};
    if (EVP_MAC_init(ctx_.get(), key.data(), key.size(), params) != 1) {
      crypto_failure("EVP_MAC_init");
    }
  }

  void begin() {
    // A null key keeps the key given at construction and restarts the computation.
    if (EVP_MAC_init(ctx_.get(), nullptr, 0, nullptr) != 1) crypto_failure("EVP_MAC_init");
  }
  void add(std::span<const std::uint8_t> bytes) {
    if (EVP_MAC_update(ctx_.get(), bytes.data(), bytes.size()) != 1) {
      crypto_failure("EVP_MAC_update");
    }
  }
  void finish(std::span<std::uint8_t, kAuthProofSize> out) {
    std::size_t length = 0;
    if (EVP_MAC_final(ctx_.get(), out.data(), &length, out.size()) != 1 || length != out.size()) {
      crypto_failure("EVP_MAC_final");
    }
  }

 private:
  std::unique_ptr<EVP_MAC_CTX, MacFreer> ctx_;
};

}  // namespace

struct PeerAuthenticator::Mac : HmacSha256 {
  using HmacSha256::HmacSha256;
};

std::uint64_t rebuild_seal_counter(std::uint64_t last_accepted, std::uint32_t low) noexcept {
  const std::uint64_t same_epoch = (last_accepted & ~kLow32) | low;
  return same_epoch > last_accepted ? same_epoch : same_epoch + (kLow32 + 1);
}

RandomSource system_random() {
  return [](std::span<std::uint8_t> out) {
    return RAND_bytes(out.data(), static_cast<int>(out.size())) == 1;
  };
}

KeyId key_id(const PreSharedKey& key) {
  HmacSha256 mac(key.bytes());
  mac.begin();
  mac.add(as_bytes(kKeyIdLabel));
  std::array<std::uint8_t, kAuthProofSize> full{};
  mac.finish(full);
  KeyId id{};
  std::copy_n(full.begin(), id.size(), id.begin());
  return id;
}

PeerAuthenticator::PeerAuthenticator(PeerAuthenticatorOptions options)
    : role_(options.role),
      gateway_identity_(options.role == AuthRole::gateway ? options.own_identity
                                                          : options.peer_identity),
      surface_identity_(options.role == AuthRole::gateway ? options.peer_identity
                                                          : options.own_identity),
      keys_(std::move(options.keys)),
      tag_size_(options.tag_size),
      random_(options.random ? std::move(options.random) : system_random()) {
  if (keys_.empty()) throw std::invalid_argument("peer authentication needs at least one key");
  if (tag_size_ != 16 && tag_size_ != 32) {
    throw std::invalid_argument("peer authentication tag size must be 16 or 32 bytes");
  }
  if (gateway_identity_.size() > 255 || surface_identity_.size() > 255) {
    throw std::invalid_argument("peer identities are at most 255 bytes");
  }
}

PeerAuthenticator::~PeerAuthenticator() = default;

bool PeerAuthenticator::fail(std::uint64_t& reason) {
  ++reason;
  state_ = State::failed;
  session_psk_.reset();
  OPENSSL_cleanse(own_challenge_.data(), own_challenge_.size());
  return false;
}

std::optional<AuthChallenge> PeerAuthenticator::make_challenge() {
  if (state_ != State::idle) {
    fail(counters_.out_of_order);
    return std::nullopt;
  }
  AuthChallenge c{};
  c[kVersionOffset] = kAuthVersion;
  c[kTagSizeOffset] = static_cast<std::uint8_t>(tag_size_);
  // The gateway names the key it proves with; the surface's key id field stays zero.
  if (role_ == AuthRole::gateway) {
    const KeyId id = key_id(keys_.front());
    std::copy(id.begin(), id.end(), c.begin() + kKeyIdOffset);
  }
  if (!random_(std::span(c).subspan(kNonceOffset, kAuthNonceSize))) {
    fail(counters_.random_failures);
    return std::nullopt;
  }
  own_challenge_ = c;
  state_ = State::challenged;
  return c;
}

std::vector<std::uint8_t> PeerAuthenticator::transcript(std::string_view purpose) const {
  const AuthChallenge& gateway_challenge =
      role_ == AuthRole::gateway ? own_challenge_ : peer_challenge_;
  const AuthChallenge& surface_challenge =
      role_ == AuthRole::gateway ? peer_challenge_ : own_challenge_;
  // Sized once and filled through a cursor: GCC 12 at -O3 cannot follow reserve() followed by
  // insert() at end() and reports a false 1-byte overflow of a size-0 region in memmove
  // (-Wstringop-overflow), which made the Release build of the quick start fail.
  std::vector<std::uint8_t> t(kTranscriptLabel.size() + purpose.size() + gateway_identity_.size() +
                              surface_identity_.size() + 4 + 2 * kAuthChallengeSize);
  auto cursor = t.begin();
  const auto append = [&cursor](std::span<const std::uint8_t> b) {
    cursor = std::copy(b.begin(), b.end(), cursor);
  };
  const auto append_byte = [&cursor](std::uint8_t b) { *cursor++ = b; };
  append(as_bytes(kTranscriptLabel));
  append_byte(0);
  append(as_bytes(purpose));
  append_byte(0);
  append_byte(static_cast<std::uint8_t>(gateway_identity_.size()));
  append(as_bytes(gateway_identity_));
  append_byte(static_cast<std::uint8_t>(surface_identity_.size()));
  append(as_bytes(surface_identity_));
  append(gateway_challenge);
  append(surface_challenge);
  return t;
}

std::optional<AuthProof> PeerAuthenticator::respond(std::span<const std::uint8_t> peer_challenge) {
  if (state_ != State::challenged) {
    fail(counters_.out_of_order);
    return std::nullopt;
  }
  if (peer_challenge.size() != kAuthChallengeSize ||
      peer_challenge[kVersionOffset] != kAuthVersion) {
    fail(counters_.malformed_challenges);
    return std::nullopt;
  }
  if (peer_challenge[kTagSizeOffset] != tag_size_) {
    fail(counters_.parameter_mismatches);
    return std::nullopt;
  }
  const auto peer_nonce = peer_challenge.subspan(kNonceOffset, kAuthNonceSize);
  if (std::equal(peer_nonce.begin(), peer_nonce.end(), own_challenge_.begin() + kNonceOffset)) {
    // Our own challenge sent back: someone is trying to make us answer ourselves.
    fail(counters_.malformed_challenges);
    return std::nullopt;
  }
  std::copy(peer_challenge.begin(), peer_challenge.end(), peer_challenge_.begin());

  if (role_ == AuthRole::gateway) {
    session_psk_.emplace(keys_.front());
  } else {
    const auto wanted = peer_challenge.subspan(kKeyIdOffset, kKeyIdSize);
    for (const PreSharedKey& key : keys_) {
      const KeyId id = key_id(key);
      if (std::equal(id.begin(), id.end(), wanted.begin())) {
        session_psk_.emplace(key);
        break;
      }
    }
    if (!session_psk_) {
      fail(counters_.unknown_keys);
      return std::nullopt;
    }
  }

  Mac mac(session_psk_->bytes());
  mac.begin();
  mac.add(transcript(role_ == AuthRole::gateway ? "gateway proof" : "surface proof"));
  AuthProof proof{};
  mac.finish(proof);
  state_ = State::responded;
  return proof;
}

bool PeerAuthenticator::verify(std::span<const std::uint8_t> peer_proof) {
  if (state_ != State::responded) return fail(counters_.out_of_order);
  if (peer_proof.size() != kAuthProofSize) return fail(counters_.bad_proofs);

  Mac mac(session_psk_->bytes());
  mac.begin();
  // The peer's role in the proof: our own proof sent back (reflection) does not match.
  mac.add(transcript(role_ == AuthRole::gateway ? "surface proof" : "gateway proof"));
  AuthProof expected{};
  mac.finish(expected);
  if (CRYPTO_memcmp(expected.data(), peer_proof.data(), expected.size()) != 0) {
    return fail(counters_.bad_proofs);
  }

  // One key per direction, so a message sent back to its sender never opens there.
  const auto derive = [this](std::string_view purpose) {
    std::unique_ptr<EVP_KDF, MacFreer> hkdf(EVP_KDF_fetch(nullptr, "HKDF", nullptr));
    std::unique_ptr<EVP_KDF_CTX, MacFreer> ctx(hkdf ? EVP_KDF_CTX_new(hkdf.get()) : nullptr);
    if (!ctx) crypto_failure("EVP_KDF_CTX_new(HKDF)");
    std::array<std::uint8_t, 2 * kAuthNonceSize> salt{};
    const AuthChallenge& g = role_ == AuthRole::gateway ? own_challenge_ : peer_challenge_;
    const AuthChallenge& s = role_ == AuthRole::gateway ? peer_challenge_ : own_challenge_;
    std::copy_n(g.begin() + kNonceOffset, kAuthNonceSize, salt.begin());
    std::copy_n(s.begin() + kNonceOffset, kAuthNonceSize, salt.begin() + kAuthNonceSize);
    std::vector<std::uint8_t> info = transcript(purpose);
    std::array<std::uint8_t, 32> ikm{};
    std::copy(session_psk_->bytes().begin(), session_psk_->bytes().end(), ikm.begin());
    char digest[] = "SHA256";
    const OSSL_PARAM params[] = {
        OSSL_PARAM_construct_utf8_string(OSSL_KDF_PARAM_DIGEST, digest, 0),
        OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_KEY, ikm.data(), ikm.size()),
        OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_SALT, salt.data(), salt.size()),
        OSSL_PARAM_construct_octet_string(OSSL_KDF_PARAM_INFO, info.data(), info.size()),
        OSSL_PARAM_END};
    std::array<std::uint8_t, 32> key{};
    const bool ok = EVP_KDF_derive(ctx.get(), key.data(), key.size(), params) == 1;
    OPENSSL_cleanse(ikm.data(), ikm.size());
    if (!ok) crypto_failure("EVP_KDF_derive(HKDF)");
    auto mac_under_key = std::make_unique<Mac>(key);
    OPENSSL_cleanse(key.data(), key.size());
    return mac_under_key;
  };
  const bool gateway = role_ == AuthRole::gateway;
  send_mac_ = derive(gateway ? "gateway to surface" : "surface to gateway");
  receive_mac_ = derive(gateway ? "surface to gateway" : "gateway to surface");
  session_psk_.reset();
  state_ = State::established;
  return true;
}

void PeerAuthenticator::tag(Mac& mac, std::uint64_t counter, std::span<const std::uint8_t> message,
                            std::span<std::uint8_t, kAuthProofSize> out) const {
  std::array<std::uint8_t, 8> counter_bytes{};
  for (std::size_t i = 0; i < counter_bytes.size(); ++i) {
    counter_bytes[i] = static_cast<std::uint8_t>(counter >> (56 - 8 * i));
  }
  mac.begin();
  mac.add(counter_bytes);
  mac.add(message);
  mac.finish(out);
}

bool PeerAuthenticator::seal(std::span<const std::uint8_t> message, std::string& out) {
  // The counter cannot wrap in practice (2^64 messages); refusing keeps the rule absolute.
  if (state_ != State::established || last_sent_ == UINT64_MAX) {
    ++counters_.not_established;
    return false;
  }
  const std::uint64_t counter = ++last_sent_;
  std::array<std::uint8_t, kAuthProofSize> full{};
  tag(*send_mac_, counter, message, full);
  out.reserve(out.size() + kSealCounterSize + message.size() + tag_size_);
  for (int shift = 24; shift >= 0; shift -= 8) {
    out.push_back(static_cast<char>(static_cast<std::uint8_t>(counter >> shift)));
  }
  out.append(reinterpret_cast<const char*>(message.data()), message.size());
  out.append(reinterpret_cast<const char*>(full.data()), tag_size_);
  ++counters_.sealed;
  return true;
}

std::optional<std::span<const std::uint8_t>> PeerAuthenticator::open(
    std::span<const std::uint8_t> sealed) {
  if (state_ != State::established) {
    ++counters_.not_established;
    return std::nullopt;
  }
  if (sealed.size() < kSealCounterSize + tag_size_) {
    ++counters_.truncated;
    return std::nullopt;
  }
  std::uint64_t low = 0;
  for (std::size_t i = 0; i < kSealCounterSize; ++i) low = low << 8 | sealed[i];
  const auto message =
      sealed.subspan(kSealCounterSize, sealed.size() - kSealCounterSize - tag_size_);
  const auto received_tag = sealed.last(tag_size_);

  const std::uint64_t counter =
      rebuild_seal_counter(last_received_, static_cast<std::uint32_t>(low));
  std::array<std::uint8_t, kAuthProofSize> expected{};
  tag(*receive_mac_, counter, message, expected);
  if (CRYPTO_memcmp(expected.data(), received_tag.data(), tag_size_) == 0) {
    last_received_ = counter;
    ++counters_.opened;
    return message;
  }
  // Refused either way; a second tag only tells a replay (authentic, old counter) from a forgery
  // for the counters.
  const std::uint64_t same_epoch = (last_received_ & ~kLow32) | low;
  if (same_epoch <= last_received_ && same_epoch != 0) {
    tag(*receive_mac_, same_epoch, message, expected);
    if (CRYPTO_memcmp(expected.data(), received_tag.data(), tag_size_) == 0) {
      ++counters_.replays;
      return std::nullopt;
    }
  }
  ++counters_.bad_tags;
  return std::nullopt;
}

}  // namespace canbridge::backbone
