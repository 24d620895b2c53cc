// How a TLS peer names itself: the PSK identity a gateway sends (`<name>/<hex key id>`, so the
// surface can pick among a gateway's keys during rotation) and the name a certificate proves.
#pragma once

#include <openssl/x509.h>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "backbone/peer_authenticator.hpp"

namespace canbridge::backbone {

// `<gateway name>/<16 lowercase hex digits of key_id(key)>`.
std::string psk_identity(std::string_view gateway_name, const PreSharedKey& key);

struct PskIdentity {
  std::string gateway_name;
  KeyId key_id{};
};
// The parts of a PSK identity; nullopt for anything else (no '/', empty name, a key id that is
// not 16 hex digits). The name may itself contain '/': the key id is after the last one.
std::optional<PskIdentity> parse_psk_identity(std::string_view identity);

// The names a certificate claims: its subjectAltName DNS entries, or when it has none, its
// subject's common name (empty when it has neither).
std::vector<std::string> certificate_names(X509* certificate);

}  // namespace canbridge::backbone
