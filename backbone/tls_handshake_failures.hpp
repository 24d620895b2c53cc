// Why TLS handshakes fail, as error codes, and the tally of them: every failure counted by
// reason and logged once per reason, so a flood of failing peers costs a counter, not a log line.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <system_error>

namespace canbridge::backbone {

enum class TlsFailure {
  not_tls = 1,           // the peer does not speak TLS 1.3 (a plain backbone peer, a scanner)
  unknown_identity,      // surface: the PSK identity names no configured gateway or key
  wrong_key,             // surface: the gateway proved with another key than the one it named
  refused_by_peer,       // the peer sent an alert: it refused our identity, key or certificate
  certificate_rejected,  // the peer's certificate does not verify against the CA (or none)
  name_not_accepted,     // a valid certificate whose name is not one this end accepts
  not_authenticated,     // gateway, psk: the surface completed without proving the key
  peer_closed,           // the connection ended during the handshake
  cancelled,             // the handshake was cancelled (a deadline, shutdown)
  other,                 // anything else (protocol errors, no shared cipher, ...)
};
inline constexpr std::size_t kTlsFailureKinds = static_cast<std::size_t>(TlsFailure::other);

const std::error_category& tls_failure_category() noexcept;
std::error_code make_error_code(TlsFailure e) noexcept;
// The counter name of a reason ("unknown_identity", ...).
std::string_view tls_failure_name(TlsFailure e) noexcept;

// What a handshake error from the TLS stack (an OpenSSL error in asio's ssl category, a socket
// error) means for us.
TlsFailure classify_tls_error(std::error_code error);

struct TlsHandshakeCounters {
  std::uint64_t succeeded = 0;
  std::array<std::uint64_t, kTlsFailureKinds> failed{};  // by TlsFailure - 1
  std::uint64_t failed_total() const;
  std::uint64_t operator[](TlsFailure e) const { return failed[static_cast<std::size_t>(e) - 1]; }
};

// Counts failures and logs the first of each reason as a warning (later ones at debug level).
class TlsFailureLog {
 public:
  explicit TlsFailureLog(std::string role) : role_(std::move(role)) {}
  void succeeded() { ++counters_.succeeded; }
  void failed(TlsFailure reason, std::string_view peer, std::string_view detail);
  const TlsHandshakeCounters& counters() const { return counters_; }

 private:
  std::string role_;  // "surface" or "gateway", for the log line
  TlsHandshakeCounters counters_;
};

}  // namespace canbridge::backbone

template <>
struct std::is_error_code_enum<canbridge::backbone::TlsFailure> : std::true_type {};
