// Keeps one outgoing backbone connection up: connects, hands each new StreamLink to the user,
// and reconnects with exponential backoff whenever the link or the connection attempt fails.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/cancellation_signal.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "backbone/link_upgrade.hpp"
#include "backbone/reconnect_backoff.hpp"
#include "backbone/stream_link.hpp"

namespace canbridge::backbone {

struct ClientOptions {
  // Wait before the next attempt: starts at backoff_min, doubles after every failed attempt or
  // link the peer refused (errc::refused_by_peer) up to backoff_max, and returns to backoff_min
  // after any other link ends.
  std::chrono::milliseconds backoff_min{100};
  std::chrono::milliseconds backoff_max{5000};
  // Bounds resolve + connect, so a silently dropped SYN does not stall reconnection for minutes.
  std::chrono::milliseconds connect_timeout{5000};
  StreamLinkOptions link;
  // Plain when empty; the TLS handshake otherwise (backbone/tls_*). Bounded by connect_timeout;
  // a failed upgrade backs off like a failed connect.
  LinkUpgrade upgrade;
};

struct ClientCounters {
  std::uint64_t attempts = 0;  // connects begun (after a successful resolve)
  std::uint64_t connects = 0;
  std::uint64_t connect_failures = 0;  // failed resolves, refused/timed-out connects or upgrades
};

// Not thread-safe: call every member on the executor's thread.
class TcpClient : public std::enable_shared_from_this<TcpClient> {
 public:
  // Called with every new link; the handler must call link->start(...) (a link it does not start
  // is closed). The client reconnects once that link has closed.
  using ConnectedHandler = std::function<void(std::shared_ptr<StreamLink> link)>;

  static std::shared_ptr<TcpClient> create(boost::asio::any_io_executor executor, std::string host,
                                           std::uint16_t port, ClientOptions options = {});
  ~TcpClient();
  TcpClient(const TcpClient&) = delete;
  TcpClient& operator=(const TcpClient&) = delete;

  // Begins connecting; call once.
  void start(ConnectedHandler on_connected);

  // Cancels the pending resolve/connect or backoff and closes the current link (its on_closed
  // runs with errc::closed); nothing of the client stays pending afterwards. Idempotent.
  void stop();

  ClientCounters counters() const { return counters_; }
  // The current link, or null while disconnected.
  std::shared_ptr<StreamLink> link() const { return link_; }

 private:
  TcpClient(boost::asio::any_io_executor executor, std::string host, std::uint16_t port,
            ClientOptions options);

  boost::asio::awaitable<void> run();
  boost::asio::awaitable<std::error_code> connect_once();
  // Runs options_.upgrade on socket_ into upgraded_, cancelled by upgrade_cancel_.
  boost::asio::awaitable<std::error_code> upgrade();
  boost::asio::awaitable<void> back_off();

  boost::asio::any_io_executor executor_;
  std::string host_;
  std::uint16_t port_;
  ClientOptions options_;
  boost::asio::ip::tcp::resolver resolver_;
  boost::asio::ip::tcp::socket socket_;  // the connection being attempted
  boost::asio::steady_timer deadline_;   // connect_timeout of the current attempt
  boost::asio::steady_timer backoff_timer_;
  boost::asio::cancellation_signal upgrade_cancel_;  // deadline or stop() during the upgrade
  std::shared_ptr<StreamLink> upgraded_;             // the link the upgrade made
  ReconnectBackoff backoff_;
  ConnectedHandler on_connected_;
  std::shared_ptr<StreamLink> link_;
  ClientCounters counters_;
  std::uint64_t attempt_ = 0;  // tells a stale deadline expiry from the current one
  bool started_ = false;
  bool stopped_ = false;
  bool failing_ = false;  // in a run of failed attempts (log the first one only)
  bool refused_ = false;  // the peer refused the latest link
};

}  // namespace canbridge::backbone
