// Accepts backbone connections on one address and hands each as a StreamLink to the user, under
// admission control: handshakes in progress are capped and time out, admitted links are capped.
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
#include <system_error>
#include <unordered_map>
#include <vector>

#include "backbone/admission_control.hpp"
#include "backbone/link_upgrade.hpp"
#include "backbone/low_priority_executor.hpp"
#include "backbone/stream_link.hpp"

namespace canbridge::backbone {

struct ServerOptions {
  StreamLinkOptions link;
  // Pause after a failed accept (e.g. EMFILE), which would otherwise fail again at once.
  std::chrono::milliseconds accept_retry_delay{100};
  // Plain when empty; the TLS handshake otherwise (backbone/tls_*).
  LinkUpgrade upgrade;
  // A connection is pending from accept until admitted() (TLS and session hello done); see
  // AdmissionControl for the caps and the deadline. The surface's process sets them from its
  // config; unlimited here for owners that never call admitted() (tests, benches).
  AdmissionLimits admission = AdmissionLimits::unlimited();
  // Connections the kernel queues before accept(); large, so a flood of connects does not make a
  // real peer's SYN wait (the accept loop drains the queue quickly). The kernel caps it at
  // net.core.somaxconn.
  int listen_backlog = 4096;
  // Steps of handshakes (the wait for a first byte, TLS work, the hand-over) run in passes of
  // their own, each behind what the established links had ready when it was posted
  // (LowPriorityQueue). A pass runs the steps queued before it started, at most this many; a
  // connection has at most one step queued, so a pass is at most one step per connection. Not
  // smaller: the steps of a flood arrive faster than passes come round on a loaded host, and a
  // cap far below the pending connections let them queue up until a configured gateway's
  // handshake passed its deadline (2 steps per pass: binds of 2.1 and 2.6 s in the rig under a
  // 64-host flood, against a bar of 2 s).
  std::size_t handshake_steps_per_pass = 64;
};

struct ServerCounters {
  std::uint64_t accepted = 0;
  std::uint64_t accept_errors = 0;
  std::uint64_t upgrade_failures = 0;  // the upgrade (TLS handshake) failed or was cancelled
  std::uint64_t left_silent = 0;       // the peer closed before it said anything
  std::uint64_t heap_trims = 0;        // freed heap pages given back after handshakes
  LowPriorityQueue::Counters handshake_steps;  // the handshakes' queue behind the links
  AdmissionCounters admission;
};

// Not thread-safe: call every member on the executor's thread.
class TcpServer : public std::enable_shared_from_this<TcpServer> {
 public:
  // Called with every accepted link once upgraded; the handler must call link->start(...) (a link
  // it does not start is closed). The link stays pending (and is closed at the handshake
  // deadline) until admitted(link) is called.
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

  // The owner accepted this link's peer (its session is bound): it is no longer pending, and
  // counts against max_links (a link beyond it is closed here). Links not from this server (a
  // serial line) are ignored.
  void admitted(const MessageLink& link);

  // The bound port (the real one when started with port 0); 0 before a successful start().
  std::uint16_t port() const noexcept { return port_; }
  ServerCounters counters() const;
  // Links accepted and not yet closed.
  std::vector<std::shared_ptr<StreamLink>> links() const;
  // Connections accepted whose coroutine still runs (upgrading, pending or admitted, or closing).
  std::size_t connections() const noexcept { return connections_.size(); }

 private:
  using ConnectionId = AdmissionControl::ConnectionId;
  // One accepted socket: its upgrade, then its link until the link closes. Small on purpose.
  struct Connection {
    ConnectionId id = 0;
    boost::asio::cancellation_signal cancel;  // ends the upgrade (eviction, deadline, stop)
    std::shared_ptr<StreamLink> link;         // once upgraded and handed to the user
    bool cancelled = false;                   // `cancel` was emitted
  };

  TcpServer(boost::asio::any_io_executor executor, ServerOptions options);

  boost::asio::awaitable<void> accept_loop();
  // Takes one accepted socket under admission control and starts serve() on it.
  void take(boost::asio::ip::tcp::socket socket, const boost::asio::ip::tcp::endpoint& peer);
  // Waits until a silent peer speaks, upgrades the socket, hands the link over and waits until it
  // closes.
  boost::asio::awaitable<void> serve(std::shared_ptr<Connection> connection,
                                     boost::asio::ip::tcp::socket socket, bool talking);
  boost::asio::awaitable<UpgradeResult> upgrade(boost::asio::ip::tcp::socket socket);
  // Closes every pending connection past its deadline; one timer for all of them.
  boost::asio::awaitable<void> deadline_loop();
  void arm_deadline();
  // Ends a connection admission gave up on: cancels its upgrade or closes its link.
  void end_connection(ConnectionId id);
  void cancel(Connection& connection);
  void connection_done(const Connection& connection, const std::string& failure);
  // Gives the heap's free pages back to the system once many connections have come and gone
  // and none is pending (glibc keeps them otherwise: the surface's RSS stayed 12 MB up after a
  // handshake flood).
  void release_freed_memory();

  boost::asio::any_io_executor executor_;
  ServerOptions options_;
  boost::asio::ip::tcp::acceptor acceptor_;
  boost::asio::steady_timer retry_timer_;
  boost::asio::steady_timer deadline_timer_;
  AcceptedHandler on_accepted_;
  // Where every connection's coroutine runs until its link closes: behind the links' own work.
  std::shared_ptr<LowPriorityQueue> handshakes_;
  AdmissionControl admission_;
  // Every connection whose coroutine runs; erased when it ends, so nothing outlives a close.
  std::unordered_map<ConnectionId, std::shared_ptr<Connection>> connections_;
  ConnectionId next_id_ = 0;
  ConnectionId connections_at_last_trim_ = 0;
  ServerCounters counters_;
  bool warned_evicted_ = false;  // each said once, then only counted
  bool warned_timeout_ = false;
  bool warned_link_cap_ = false;
  bool warned_source_ = false;
  std::uint16_t port_ = 0;
  bool started_ = false;
  bool stopped_ = false;
};

}  // namespace canbridge::backbone
