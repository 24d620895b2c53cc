#include "backbone/tls_identity.hpp"

#include <openssl/objects.h>
#include <openssl/x509v3.h>

#include <memory>

namespace canbridge::backbone {

namespace {

constexpr char kHexDigits[] = "0123456789abcdef";

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

}  // namespace

std::string psk_identity(std::string_view gateway_name, const PreSharedKey& key) {
  std::string identity(gateway_name);
  identity.push_back('/');
  for (const std::uint8_t byte : key_id(key)) {
    identity.push_back(kHexDigits[byte >> 4]);
    identity.push_back(kHexDigits[byte & 0x0F]);
  }
  return identity;
}

std::optional<PskIdentity> parse_psk_identity(std::string_view identity) {
  const auto slash = identity.rfind('/');
  if (slash == std::string_view::npos || slash == 0) return std::nullopt;
  const std::string_view hex = identity.substr(slash + 1);
  if (hex.size() != 2 * kKeyIdSize) return std::nullopt;
  PskIdentity parsed;
  parsed.gateway_name = std::string(identity.substr(0, slash));
  for (std::size_t i = 0; i < kKeyIdSize; ++i) {
    const int high = hex_value(hex[2 * i]);
    const int low = hex_value(hex[2 * i + 1]);
    if (high < 0 || low < 0) return std::nullopt;
    parsed.key_id[i] = static_cast<std::uint8_t>(high << 4 | low);
  }
  return parsed;
}

std::vector<std::string> certificate_names(X509* certificate) {
  std::vector<std::string> names;
  if (!certificate) return names;
  using Names = std::unique_ptr<GENERAL_NAMES, decltype(&GENERAL_NAMES_free)>;
  Names alt(static_cast<GENERAL_NAMES*>(
                X509_get_ext_d2i(certificate, NID_subject_alt_name, nullptr, nullptr)),
            &GENERAL_NAMES_free);
  if (alt) {
    for (int i = 0; i < sk_GENERAL_NAME_num(alt.get()); ++i) {
      const GENERAL_NAME* name = sk_GENERAL_NAME_value(alt.get(), i);
      if (name->type != GEN_DNS) continue;
      const ASN1_IA5STRING* dns = name->d.dNSName;
      names.emplace_back(reinterpret_cast<const char*>(ASN1_STRING_get0_data(dns)),
                         static_cast<std::size_t>(ASN1_STRING_length(dns)));
    }
  }
  if (!names.empty()) return names;
  X509_NAME* subject = X509_get_subject_name(certificate);
  const int index = X509_NAME_get_index_by_NID(subject, NID_commonName, -1);
  if (index < 0) return names;
  const ASN1_STRING* cn = X509_NAME_ENTRY_get_data(X509_NAME_get_entry(subject, index));
  names.emplace_back(reinterpret_cast<const char*>(ASN1_STRING_get0_data(cn)),
                     static_cast<std::size_t>(ASN1_STRING_length(cn)));
  return names;
}

}  // namespace canbridge::backbone
