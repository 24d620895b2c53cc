// TLS 1.3 with mutual authentication for TCP backbones (docs/security.md): the TLS contexts a
// gateway (client) and a surface (server) build from their credentials, and the LinkUpgrade that
// runs the handshake on a connected socket and hands back a StreamLink whose
// authenticated_peer() is the identity the peer proved.
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl/context.hpp>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include "backbone/link_upgrade.hpp"
#include "backbone/pre_shared_keys.hpp"
#include "backbone/tls_handshake_failures.hpp"

namespace canbridge::backbone {

// Gateway (TLS client) proving itself with its pre-shared key: identity
// `<gateway_name>/<hex key_id(keys[0])>`, key keys[0]. The surface proves itself by completing the
// handshake with the same key; its link's authenticated_peer() is then surface_name.
struct TlsGatewayPsk {
  std::string gateway_name;
  std::vector<PreSharedKey> keys;  // keys[0] is used; at least one
  std::string surface_name = "surface";
  // When set, asked for the keys at every handshake instead of `keys` (a KeyFileWatch: a key
  // rotated in the file is used from the next connection, no restart).
  std::function<std::vector<PreSharedKey>()> current_keys;
};

// Surface (TLS server) accepting gateways by pre-shared key: each configured gateway's keys (one,
// or two while rotating); the identity's key id picks the key. Unknown names and ids are refused.
struct TlsSurfacePsk {
  std::map<std::string, std::vector<PreSharedKey>, std::less<>> gateways;
  // When set, asked at every handshake for a configured gateway's keys as they are now (a
  // KeyFileWatch per gateway: keys added to or removed from its file count from the next
  // connection, no restart) instead of the ones in `gateways`, which then only lists the names.
  std::function<std::vector<PreSharedKey>(const std::string& gateway)> current_keys;
};

// Either end with certificates of a private CA: this end's chain and private key (PEM; the key
// file's permissions are checked like a key file's) and the CA the peer's certificate must chain
// to. The peer's identity is its certificate's subjectAltName DNS name (else its CN) and must be
// one of accepted_names (surface: the configured gateways; gateway: the surface's name).
struct TlsCertificates {
  bool server = false;  // the surface's end
  std::string certificate_file;
  std::string private_key_file;
  std::string ca_file;
  std::vector<std::string> accepted_names;
};

using TlsCredentials = std::variant<TlsGatewayPsk, TlsSurfacePsk, TlsCertificates>;

// Not thread-safe: run every upgrade on one executor thread (as every backbone object).
class TlsUpgrade : public std::enable_shared_from_this<TlsUpgrade> {
 public:
  // Builds the context; throws std::runtime_error naming the file and the fix when a certificate,
  // key or CA cannot be used (start-up only).
  static std::shared_ptr<TlsUpgrade> create(TlsCredentials credentials);
  ~TlsUpgrade();
  TlsUpgrade(const TlsUpgrade&) = delete;
  TlsUpgrade& operator=(const TlsUpgrade&) = delete;

  // The handshake on `socket`, then a link over the TLS stream. Honours cancellation of the
  // awaiting coroutine (terminal): the socket is closed and the result says cancelled. Every
  // failure is a TlsFailure, counted and logged once per reason.
  boost::asio::awaitable<UpgradeResult> upgrade(boost::asio::ip::tcp::socket socket,
                                                StreamLinkOptions options);
  // For ClientOptions::upgrade / ServerOptions::upgrade; holds this object alive.
  LinkUpgrade link_upgrade();

  bool is_server() const noexcept { return server_; }
  const TlsHandshakeCounters& counters() const { return failures_.counters(); }

  struct Handshake;  // per-handshake state the OpenSSL callbacks fill (tls_upgrade.cpp)

 private:
  explicit TlsUpgrade(TlsCredentials credentials);
  void configure_common();
  void configure_gateway_psk();
  void configure_surface_psk();
  void configure_certificates();

  TlsCredentials credentials_;
  bool server_ = false;
  std::string gateway_identity_;  // gateway psk: the identity sent
  boost::asio::ssl::context context_;
  TlsFailureLog failures_;
};

}  // namespace canbridge::backbone
