// Accepts backbone connections on one address and hands each as a StreamLink to the user.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include "backbone/link_upgrade.hpp"
#include "backbone/stream_link.hpp"

namespace canbridge::backbone {

struct ServerOptions {
  StreamLinkOptions link;
  // Pause after a failed accept (e.g. EMFILE), which would otherwise fail again at once.
  std::chrono::milliseconds accept_retry_delay{100};
  // Plain when empty; the TLS handshake otherwise (backbone/tls_*).
  LinkUpgrade upgrade;
};

struct ServerCounters {
  std::uint64_t accepted = 0;
  std::uint64_t accept_errors = 0;
};

// Not thread-safe: call every member on the executor's thread.
class TcpServer : public std::enable_shared_from_this<TcpServer> {
 public:
  // Called with every accepted link; the handler must call link->start(...) (a link it does not
  // start is closed).
  using AcceptedHandler = std::function<void(std::shared_ptr<StreamLink> link)>;

  static std::shared_ptr<TcpServer> create(boost::asio::any_io_executor executor,
                                           ServerOptions options = {});
  ~TcpServer();
  TcpServer(const TcpServer&) = delete;
  TcpServer& operator=(const TcpServer&) = delete;

  // Binds (port 0 picks a free port, see port()), listens and starts accepting. Call once.
  std::error_code start(const boost::asio::ip::tcp::endpoint& endpoint,
                        AcceptedHandler on_accepted);
  // Same, with the address in text form ("0.0.0.0", "::", "127.0.0.1", ...).
  std::error_code start(const std::string& address, std::uint16_t port,
                        AcceptedHandler on_accepted);

  // Closes the acceptor and every live link; nothing of the server stays pending. Idempotent.
  void stop();

  // The bound port (the real one when started with port 0); 0 before a successful start().
  std::uint16_t port() const noexcept { return port_; }
  ServerCounters counters() const { return counters_; }
  // Links accepted and not yet closed.
  std::vector<std::shared_ptr<StreamLink>> links() const;

 private:
  TcpServer(boost::asio::any_io_executor executor, ServerOptions options);

  boost::asio::awaitable<void> accept_loop();

  boost::asio::any_io_executor executor_;
  ServerOptions options_;
  boost::asio::ip::tcp::acceptor acceptor_;
  boost::asio::steady_timer retry_timer_;
  AcceptedHandler on_accepted_;
  std::vector<std::weak_ptr<StreamLink>> links_;
  ServerCounters counters_;
  std::uint16_t port_ = 0;
  bool started_ = false;
  bool stopped_ = false;
};

}  // namespace canbridge::backbone
