#include "backbone/tls_handshake_failures.hpp"

#include <openssl/err.h>
#include <openssl/ssl.h>
#include <spdlog/spdlog.h>

#include <boost/asio/error.hpp>
#include <boost/asio/ssl/error.hpp>
#include <numeric>

namespace canbridge::backbone {

namespace {

class Category final : public std::error_category {
 public:
  const char* name() const noexcept override { return "tls"; }
  // A cancelled handshake compares equal to std::errc::operation_canceled, like any cancelled
  // operation (TcpClient turns that into a timeout).
  std::error_condition default_error_condition(int value) const noexcept override {
    if (static_cast<TlsFailure>(value) == TlsFailure::cancelled) {
      return std::errc::operation_canceled;
    }
    return {value, *this};
  }
  std::string message(int value) const override {
    switch (static_cast<TlsFailure>(value)) {
      case TlsFailure::not_tls:
        return "TLS handshake failed: the peer does not speak TLS 1.3";
      case TlsFailure::unknown_identity:
        return "TLS handshake refused: unknown gateway identity or key id";
      case TlsFailure::wrong_key:
        return "TLS handshake refused: the gateway's key does not match";
      case TlsFailure::refused_by_peer:
        return "TLS handshake refused by the peer (wrong key, identity or certificate?)";
      case TlsFailure::certificate_rejected:
        return "TLS handshake refused: the peer's certificate does not verify";
      case TlsFailure::name_not_accepted:
        return "TLS handshake refused: the peer's certificate names no accepted identity";
      case TlsFailure::not_authenticated:
        return "TLS handshake refused: the peer did not prove the pre-shared key";
      case TlsFailure::peer_closed:
        return "TLS handshake failed: the peer closed the connection";
      case TlsFailure::cancelled:
        return "TLS handshake cancelled";
      case TlsFailure::other:
        return "TLS handshake failed";
    }
    return "unknown TLS failure";
  }
};

}  // namespace

const std::error_category& tls_failure_category() noexcept {
  static const Category category;
  return category;
}

std::error_code make_error_code(TlsFailure e) noexcept {
  return {static_cast<int>(e), tls_failure_category()};
}

std::string_view tls_failure_name(TlsFailure e) noexcept {
  switch (e) {
    case TlsFailure::not_tls:
      return "not_tls";
    case TlsFailure::unknown_identity:
      return "unknown_identity";
    case TlsFailure::wrong_key:
      return "wrong_key";
    case TlsFailure::refused_by_peer:
      return "refused_by_peer";
    case TlsFailure::certificate_rejected:
      return "certificate_rejected";
    case TlsFailure::name_not_accepted:
      return "name_not_accepted";
    case TlsFailure::not_authenticated:
      return "not_authenticated";
    case TlsFailure::peer_closed:
      return "peer_closed";
    case TlsFailure::cancelled:
      return "cancelled";
    case TlsFailure::other:
      return "other";
  }
  return "unknown";
}

TlsFailure classify_tls_error(std::error_code error) {
  if (error.category() == tls_failure_category()) return static_cast<TlsFailure>(error.value());
  if (error == std::errc::operation_canceled) return TlsFailure::cancelled;
  const boost::system::error_code eof = boost::asio::error::eof;
  const boost::system::error_code truncated = boost::asio::ssl::error::stream_truncated;
  if (error == std::error_code(eof) || error == std::error_code(truncated) ||
      error == std::errc::connection_reset || error == std::errc::broken_pipe) {
    return TlsFailure::peer_closed;
  }
  const boost::system::error_code ssl_probe(1, boost::asio::error::get_ssl_category());
  if (error.category() != std::error_code(ssl_probe).category()) return TlsFailure::other;
  const int reason = ERR_GET_REASON(static_cast<unsigned long>(error.value()));
  if (reason >= SSL_AD_REASON_OFFSET) return TlsFailure::refused_by_peer;  // an alert received
  switch (reason) {
    case SSL_R_WRONG_VERSION_NUMBER:
    case SSL_R_UNKNOWN_PROTOCOL:
    case SSL_R_UNSUPPORTED_PROTOCOL:
    case SSL_R_HTTP_REQUEST:
    case SSL_R_HTTPS_PROXY_REQUEST:
    case SSL_R_PACKET_LENGTH_TOO_LONG:
    case SSL_R_RECORD_LENGTH_MISMATCH:
    case SSL_R_WRONG_SSL_VERSION:
    case SSL_R_VERSION_TOO_LOW:
      return TlsFailure::not_tls;
    case SSL_R_BINDER_DOES_NOT_VERIFY:
      return TlsFailure::wrong_key;
    case SSL_R_CERTIFICATE_VERIFY_FAILED:
    case SSL_R_PEER_DID_NOT_RETURN_A_CERTIFICATE:
      return TlsFailure::certificate_rejected;
    default:
      return TlsFailure::other;
  }
}

std::uint64_t TlsHandshakeCounters::failed_total() const {
  return std::accumulate(failed.begin(), failed.end(), std::uint64_t{0});
}

void TlsFailureLog::failed(TlsFailure reason, std::string_view peer, std::string_view detail) {
  auto& count = counters_.failed[static_cast<std::size_t>(reason) - 1];
  ++count;
  const std::string what = make_error_code(reason).message();
  if (count == 1) {
    spdlog::warn(
        "backbone: {} TLS handshake with {} failed: {}{}{} (first occurrence; further ones are "
        "only counted as {})",
        role_, peer, what, detail.empty() ? "" : ": ", detail, tls_failure_name(reason));
  } else {
    spdlog::debug("backbone: {} TLS handshake with {} failed: {}{}{}", role_, peer, what,
                  detail.empty() ? "" : ": ", detail);
  }
}

}  // namespace canbridge::backbone
