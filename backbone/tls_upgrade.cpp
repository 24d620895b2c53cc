#include "backbone/tls_upgrade.hpp"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <openssl/ssl.h>
#include <openssl/x509_vfy.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/ssl/stream.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <cerrno>
#include <cstring>
#include <optional>
#include <stdexcept>

#include "backbone/peer_authenticator.hpp"
#include "backbone/tls_identity.hpp"
#include "coro/no_error.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
namespace ssl = asio::ssl;
using asio::ip::tcp;

// What the OpenSSL callbacks of one handshake read and write; attached to the SSL object only
// while the handshake runs (after it, no callback of ours is ever called again).
struct TlsUpgrade::Handshake {
  const TlsCredentials* credentials = nullptr;
  const std::string* gateway_identity = nullptr;
  // Gateway psk: the key this handshake proves with (the current one when keys are watched).
  std::optional<PreSharedKey> gateway_key;
  std::string rotated_identity;  // gateway_identity's storage when the key was watched
  std::string peer;              // the identity the peer proved
  std::optional<TlsFailure> failure;
  std::string detail;

  void fail(TlsFailure reason, std::string why) {
    if (failure) return;  // the first reason is the real one
    failure = reason;
    detail = std::move(why);
  }
};

namespace {

using coro::kNoError;
constexpr const char* kCipherSuites = "TLS_AES_128_GCM_SHA256:TLS_CHACHA20_POLY1305_SHA256";
// Far more than any PEM private key; a bigger file is not one.
constexpr std::size_t kMaxPrivateKeyFileSize = 64 * 1024;

int handshake_index() {
  static const int index = SSL_get_ex_new_index(0, nullptr, nullptr, nullptr, nullptr);
  return index;
}

TlsUpgrade::Handshake* handshake_of(SSL* ssl) {
  return ssl ? static_cast<TlsUpgrade::Handshake*>(SSL_get_ex_data(ssl, handshake_index()))
             : nullptr;
}

// A name a stranger sent, fit for a log line: printable ASCII only, bounded.
std::string printable(std::string_view text) {
  std::string out;
  for (const char c : text.substr(0, 64)) out.push_back(c >= 0x20 && c < 0x7F ? c : '?');
  if (text.size() > 64) out += "...";
  return out;
}

std::string describe(const tcp::endpoint& endpoint) {
  return endpoint.address().to_string() + ":" + std::to_string(endpoint.port());
}

// An external PSK as OpenSSL wants it: a TLS 1.3 session with the key as its master secret and
// a SHA-256 suite (the handshake hash of both suites we offer).
SSL_SESSION* psk_session(SSL* ssl, const PreSharedKey& key) {
  static constexpr unsigned char kAes128GcmSha256[] = {0x13, 0x01};
  const SSL_CIPHER* cipher = SSL_CIPHER_find(ssl, kAes128GcmSha256);
  if (!cipher) return nullptr;
  SSL_SESSION* session = SSL_SESSION_new();
  if (!session || !SSL_SESSION_set1_master_key(session, key.bytes().data(), key.bytes().size()) ||
      !SSL_SESSION_set_cipher(session, cipher) ||
      !SSL_SESSION_set_protocol_version(session, TLS1_3_VERSION)) {
    SSL_SESSION_free(session);
    return nullptr;
  }
  return session;
}

// Gateway: offers its identity and key. OpenSSL takes ownership of the session.
int use_psk_session(SSL* ssl, const EVP_MD* md, const unsigned char** id, std::size_t* id_length,
                    SSL_SESSION** session) {
  *session = nullptr;
  auto* handshake = handshake_of(ssl);
  if (!handshake) return 0;
  const auto& psk = std::get<TlsGatewayPsk>(*handshake->credentials);
  SSL_SESSION* made =
      psk_session(ssl, handshake->gateway_key ? *handshake->gateway_key : psk.keys.front());
  if (!made) return 0;
  if (md && md != SSL_CIPHER_get_handshake_digest(SSL_SESSION_get0_cipher(made))) {
    SSL_SESSION_free(made);  // the server picked a suite our key is not set up for
    return 1;
  }
  *id = reinterpret_cast<const unsigned char*>(handshake->gateway_identity->data());
  *id_length = handshake->gateway_identity->size();
  *session = made;
  return 1;
}

// Surface: the gateway's identity names it and the key it proves with. Returning 0 ends the
// handshake: an unknown identity never gets further.
int find_psk_session(SSL* ssl, const unsigned char* identity, std::size_t identity_length,
                     SSL_SESSION** session) {
  *session = nullptr;
  auto* handshake = handshake_of(ssl);
  if (!handshake) return 0;
  const std::string_view text(reinterpret_cast<const char*>(identity), identity_length);
  const auto parsed = parse_psk_identity(text);
  if (!parsed) {
    handshake->fail(TlsFailure::unknown_identity,
                    "malformed PSK identity '" + printable(text) + "'");
    return 0;
  }
  const auto& psk = std::get<TlsSurfacePsk>(*handshake->credentials);
  const auto gateway = psk.gateways.find(parsed->gateway_name);
  if (gateway == psk.gateways.end()) {
    handshake->fail(TlsFailure::unknown_identity,
                    "no configured gateway '" + printable(parsed->gateway_name) + "'");
    return 0;
  }
  const std::vector<PreSharedKey> keys =
      psk.current_keys ? psk.current_keys(gateway->first) : gateway->second;
  for (const PreSharedKey& key : keys) {
    if (key_id(key) != parsed->key_id) continue;
    *session = psk_session(ssl, key);
    if (!*session) return 0;
    handshake->peer = gateway->first;
    return 1;
  }
  handshake->fail(TlsFailure::unknown_identity,
                  "gateway '" + gateway->first + "' proves with a key id not in its key file");
  return 0;
}

// Certificates: OpenSSL's chain verification, then the leaf's name against the accepted ones.
int verify_certificate(int preverified, X509_STORE_CTX* store) {
  auto* ssl =
      static_cast<SSL*>(X509_STORE_CTX_get_ex_data(store, SSL_get_ex_data_X509_STORE_CTX_idx()));
  auto* handshake = handshake_of(ssl);
  if (!handshake) return 0;
  if (!preverified) {
    handshake->fail(TlsFailure::certificate_rejected,
                    X509_verify_cert_error_string(X509_STORE_CTX_get_error(store)));
    return 0;
  }
  if (X509_STORE_CTX_get_error_depth(store) != 0) return 1;  // a CA of the chain
  const auto& certificates = std::get<TlsCertificates>(*handshake->credentials);
  const auto names = certificate_names(X509_STORE_CTX_get_current_cert(store));
  for (const auto& name : names) {
    for (const auto& accepted : certificates.accepted_names) {
      if (name != accepted) continue;
      handshake->peer = name;
      return 1;
    }
  }
  std::string claimed;
  for (const auto& name : names) claimed += (claimed.empty() ? "'" : ", '") + printable(name) + "'";
  handshake->fail(TlsFailure::name_not_accepted,
                  "certificate names " + (claimed.empty() ? std::string("nothing") : claimed));
  X509_STORE_CTX_set_error(store, X509_V_ERR_APPLICATION_VERIFICATION);
  return 0;
}

// The private key's PEM text, read from the opened file once its permissions are checked like a
// pre-shared key file's (so a swap after the check cannot slip through).
std::string read_private_key(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    throw std::runtime_error(path + ": cannot open the private key: " + std::strerror(errno));
  }
  struct stat status {};
  if (::fstat(fd, &status) != 0) {
    const int error = errno;
    ::close(fd);
    throw std::runtime_error(path + ": cannot stat the private key: " + std::strerror(error));
  }
  if (auto problem = check_key_file_permissions(status, ::geteuid(), path)) {
    ::close(fd);
    throw std::runtime_error(problem->message);
  }
  std::string text;
  char chunk[4096];
  for (;;) {
    const ssize_t n = ::read(fd, chunk, sizeof chunk);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    text.append(chunk, static_cast<std::size_t>(n));
    if (text.size() > kMaxPrivateKeyFileSize) break;
  }
  OPENSSL_cleanse(chunk, sizeof chunk);
  ::close(fd);
  if (text.size() > kMaxPrivateKeyFileSize) {
    OPENSSL_cleanse(text.data(), text.size());
    throw std::runtime_error(path + ": too large for a private key");
  }
  return text;
}

void require(const boost::system::error_code& ec, const std::string& what) {
  if (ec) throw std::runtime_error(what + ": " + ec.message());
}

}  // namespace

std::shared_ptr<TlsUpgrade> TlsUpgrade::create(TlsCredentials credentials) {
  return std::shared_ptr<TlsUpgrade>(new TlsUpgrade(std::move(credentials)));
}

TlsUpgrade::TlsUpgrade(TlsCredentials credentials)
    : credentials_(std::move(credentials)),
      server_(std::holds_alternative<TlsSurfacePsk>(credentials_) ||
              (std::holds_alternative<TlsCertificates>(credentials_) &&
               std::get<TlsCertificates>(credentials_).server)),
      context_(server_ ? ssl::context::tls_server : ssl::context::tls_client),
      failures_(server_ ? "surface" : "gateway") {
  configure_common();
  if (std::holds_alternative<TlsGatewayPsk>(credentials_)) configure_gateway_psk();
  if (std::holds_alternative<TlsSurfacePsk>(credentials_)) configure_surface_psk();
  if (std::holds_alternative<TlsCertificates>(credentials_)) configure_certificates();
}

TlsUpgrade::~TlsUpgrade() = default;

void TlsUpgrade::configure_common() {
  SSL_CTX* ctx = context_.native_handle();
  // TLS 1.3 only: no downgrade, and its handshake encrypts the certificates.
  if (!SSL_CTX_set_min_proto_version(ctx, TLS1_3_VERSION) ||
      !SSL_CTX_set_max_proto_version(ctx, TLS1_3_VERSION) ||
      !SSL_CTX_set_ciphersuites(ctx, kCipherSuites)) {
    throw std::runtime_error("TLS: cannot restrict OpenSSL to TLS 1.3");
  }
  // Every connection proves its identity afresh: no resumption tickets to steal or replay.
  SSL_CTX_set_options(ctx, SSL_OP_NO_TICKET);
  SSL_CTX_set_num_tickets(ctx, 0);
  SSL_CTX_set_session_cache_mode(ctx, SSL_SESS_CACHE_OFF);
}

void TlsUpgrade::configure_gateway_psk() {
  const auto& psk = std::get<TlsGatewayPsk>(credentials_);
  if (psk.keys.empty())
    throw std::runtime_error("TLS psk: gateway " + psk.gateway_name + " has no key");
  gateway_identity_ = psk_identity(psk.gateway_name, psk.keys.front());
  SSL_CTX* ctx = context_.native_handle();
  SSL_CTX_set_psk_use_session_callback(ctx, use_psk_session);
  // A surface that answered with a certificate instead of the key would prove nothing: with no
  // CA loaded, any certificate fails verification (and upgrade() checks the PSK was used).
  SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER, nullptr);
}

void TlsUpgrade::configure_surface_psk() {
  const auto& psk = std::get<TlsSurfacePsk>(credentials_);
  for (const auto& [name, keys] : psk.gateways) {
    if (keys.empty()) throw std::runtime_error("TLS psk: gateway " + name + " has no key");
  }
  SSL_CTX_set_psk_find_session_callback(context_.native_handle(), find_psk_session);
}

void TlsUpgrade::configure_certificates() {
  const auto& certificates = std::get<TlsCertificates>(credentials_);
  boost::system::error_code ec;
  context_.use_certificate_chain_file(certificates.certificate_file, ec);
  require(ec, certificates.certificate_file + ": cannot load the certificate chain");
  std::string key = read_private_key(certificates.private_key_file);
  context_.use_private_key(asio::buffer(key), ssl::context::pem, ec);
  OPENSSL_cleanse(key.data(), key.size());
  require(ec, certificates.private_key_file + ": cannot load the private key");
  if (!SSL_CTX_check_private_key(context_.native_handle())) {
    throw std::runtime_error(certificates.private_key_file + ": the private key does not match " +
                             certificates.certificate_file);
  }
  context_.load_verify_file(certificates.ca_file, ec);
  require(ec, certificates.ca_file + ": cannot load the CA certificate");
  if (certificates.accepted_names.empty()) {
    throw std::runtime_error("TLS certificates: no peer name is accepted");
  }
  SSL_CTX_set_verify(context_.native_handle(), SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT,
                     verify_certificate);
}

asio::awaitable<UpgradeResult> TlsUpgrade::upgrade(tcp::socket socket, StreamLinkOptions options) {
  auto self = shared_from_this();  // the context and counters outlive the handshake
  boost::system::error_code ignored;
  const std::string peer = describe(socket.remote_endpoint(ignored));
  // The handshake's flights are small and latency-bound, as the messages after it.
  socket.set_option(tcp::no_delay(true), ignored);
  ssl::stream<tcp::socket> stream(std::move(socket), context_);
  SSL* ssl = stream.native_handle();
  Handshake handshake;
  handshake.credentials = &credentials_;
  handshake.gateway_identity = &gateway_identity_;
  if (const auto* psk = std::get_if<TlsGatewayPsk>(&credentials_); psk && psk->current_keys) {
    std::vector<PreSharedKey> keys = psk->current_keys();
    if (!keys.empty()) {
      handshake.gateway_key = keys.front();
      handshake.rotated_identity = psk_identity(psk->gateway_name, keys.front());
      handshake.gateway_identity = &handshake.rotated_identity;
    }
  }
  SSL_set_ex_data(ssl, handshake_index(), &handshake);
  auto [ec] = co_await stream.async_handshake(
      server_ ? ssl::stream_base::server : ssl::stream_base::client, kNoError);
  SSL_set_ex_data(ssl, handshake_index(), nullptr);

  if (!ec && !handshake.failure) {
    // What proved the peer: a PSK handshake must really have used the key (SSL_session_reused
    // is how OpenSSL says so for TLS 1.3 PSKs); a certificate handshake must have named the peer.
    if (std::holds_alternative<TlsGatewayPsk>(credentials_)) {
      if (SSL_session_reused(ssl)) {
        handshake.peer = std::get<TlsGatewayPsk>(credentials_).surface_name;
      } else {
        handshake.fail(TlsFailure::not_authenticated, "the surface did not use the key");
      }
    } else if (std::holds_alternative<TlsSurfacePsk>(credentials_)) {
      if (!SSL_session_reused(ssl) || handshake.peer.empty()) {
        handshake.fail(TlsFailure::not_authenticated, "the gateway did not prove a key");
      }
    } else if (handshake.peer.empty()) {
      handshake.fail(TlsFailure::certificate_rejected, "no certificate name was checked");
    }
  }
  if (ec || handshake.failure) {
    const TlsFailure reason = handshake.failure ? *handshake.failure : classify_tls_error(ec);
    failures_.failed(reason, peer, handshake.failure ? handshake.detail : ec.message());
    stream.lowest_layer().close(ignored);
    co_return UpgradeResult{nullptr, make_error_code(reason)};
  }
  failures_.succeeded();
  spdlog::debug("backbone: TLS handshake with {} done: peer '{}', {}", peer, handshake.peer,
                SSL_get_cipher_name(ssl));
  co_return UpgradeResult{StreamLink::create(std::move(stream), handshake.peer, options), {}};
}

LinkUpgrade TlsUpgrade::link_upgrade() {
  return [self = shared_from_this()](tcp::socket socket, StreamLinkOptions options) {
    return self->upgrade(std::move(socket), options);
  };
}

}  // namespace canbridge::backbone
