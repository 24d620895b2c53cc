#include "backbone/tcp_server.hpp"

#include <spdlog/spdlog.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <exception>
#include <tuple>

#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
using asio::ip::tcp;

namespace {
using coro::kNoError;
using Clock = AdmissionControl::Clock;
// Connections taken from the kernel's queue per wake-up; then the loop yields to other work, so
// that under a flood of connects the established sessions' reads, writes and keepalives still
// run every few milliseconds (on the rig's slow syscalls, 256 at a time held them up for tens
// of milliseconds, and seconds on a loaded host). A refused connection costs accept and close.
constexpr int kAcceptBatch = 16;
// Handshakes (TLS contexts, buffers, coroutine frames) are freed in an order that leaves glibc's
// heap full of holes it does not give back by itself; after this many connections, the next time
// nothing is pending, the free pages go back to the system (TcpServer::release_freed_memory).
constexpr std::uint64_t kConnectionsBetweenTrims = 256;

// Who a connection comes from, for the per-source throttle: the address's bytes, an IPv6
// address cut to its /64 (one host or site usually holds a whole /64), a v4-mapped one as v4.
AdmissionControl::Source source_of(const tcp::endpoint& peer) {
  const auto address = peer.address();
  if (address.is_unspecified()) return {};
  if (address.is_v4()) {
    const auto bytes = address.to_v4().to_bytes();
    return {bytes.begin(), bytes.end()};
  }
  const auto v6 = address.to_v6();
  if (v6.is_v4_mapped()) {
    const auto bytes = asio::ip::make_address_v4(asio::ip::v4_mapped, v6).to_bytes();
    return {bytes.begin(), bytes.end()};
  }
  const auto bytes = v6.to_bytes();
  return {bytes.begin(), bytes.begin() + 8};
}
}  // namespace

std::shared_ptr<TcpServer> TcpServer::create(asio::any_io_executor executor,
                                             ServerOptions options) {
  return std::shared_ptr<TcpServer>(new TcpServer(std::move(executor), std::move(options)));
}

TcpServer::TcpServer(asio::any_io_executor executor, ServerOptions options)
    : executor_(std::move(executor)),
      options_(std::move(options)),
      acceptor_(executor_),
      retry_timer_(executor_),
      deadline_timer_(executor_, asio::steady_timer::time_point::max()),
      handshakes_(LowPriorityQueue::create(executor_, options_.handshake_steps_per_pass)),
      admission_(options_.admission) {
  // Every accepted link warns once per kind of bad input for the whole server.
  if (!options_.link.warnings) options_.link.warnings = std::make_shared<StreamLinkWarnings>();
}

TcpServer::~TcpServer() = default;

std::error_code TcpServer::start(const std::string& address, std::uint16_t port,
                                 AcceptedHandler on_accepted) {
  boost::system::error_code ec;
  const auto ip = asio::ip::make_address(address, ec);
  if (ec) return ec;
  return start(tcp::endpoint(ip, port), std::move(on_accepted));
}

std::error_code TcpServer::start(const tcp::endpoint& endpoint, AcceptedHandler on_accepted) {
  if (started_ || stopped_) return std::make_error_code(std::errc::operation_not_permitted);
  boost::system::error_code ec;
  acceptor_.open(endpoint.protocol(), ec);
  if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
  // Accepted sockets inherit the receive buffer from the listener, and the TCP window scale is
  // fixed during the handshake, so the size has to be set here already.
  if (!ec && options_.link.socket_buffer_size > 0) {
    acceptor_.set_option(asio::socket_base::receive_buffer_size(options_.link.socket_buffer_size),
                         ec);
  }
  if (!ec) acceptor_.bind(endpoint, ec);
  if (!ec) acceptor_.listen(std::max(options_.listen_backlog, 1), ec);
  if (!ec) port_ = acceptor_.local_endpoint(ec).port();
  if (ec) {
    boost::system::error_code ignored;
    acceptor_.close(ignored);
    port_ = 0;
    return ec;
  }
  started_ = true;
  on_accepted_ = std::move(on_accepted);
  spdlog::info("backbone: listening on {}:{}", endpoint.address().to_string(), port_);
  // The loops hold the server alive until stop() lets them finish; if one fails (a handler
  // threw), the server says why and stops: its links close, and nothing is left half-listening.
  auto on_end = [self = shared_from_this()](const std::string& failure) {
    if (failure.empty()) return;
    spdlog::error("backbone: server on port {} stopped: {}", self->port_, failure);
    self->stop();
    self->on_accepted_ = nullptr;
  };
  coro::spawn_owned(executor_, accept_loop(), on_end);
  coro::spawn_owned(executor_, deadline_loop(), on_end);
  return {};
}

void TcpServer::stop() {
  if (stopped_) return;
  stopped_ = true;
  boost::system::error_code ignored;
  acceptor_.close(ignored);
  retry_timer_.cancel();
  deadline_timer_.cancel();
  // Each connection's coroutine ends on its own once cancelled or its link closed, and erases it.
  const auto now = Clock::now();
  for (auto& [id, connection] : std::unordered_map(connections_)) {
    admission_.on_closed(id, now);
    cancel(*connection);
  }
}

void TcpServer::cancel(Connection& connection) {
  if (connection.link) {
    connection.link->close();
  } else if (!connection.cancelled) {
    connection.cancelled = true;
    connection.cancel.emit(asio::cancellation_type::terminal);
  }
}

ServerCounters TcpServer::counters() const {
  ServerCounters counters = counters_;
  counters.admission = admission_.counters();
  counters.handshake_steps = handshakes_->counters();
  return counters;
}

std::vector<std::shared_ptr<StreamLink>> TcpServer::links() const {
  std::vector<std::shared_ptr<StreamLink>> live;
  for (const auto& [id, connection] : connections_) {
    if (connection->link && connection->link->is_open()) live.push_back(connection->link);
  }
  return live;
}

void TcpServer::admitted(const MessageLink& link) {
  const auto it = std::find_if(connections_.begin(), connections_.end(),
                               [&](const auto& c) { return c.second->link.get() == &link; });
  if (it == connections_.end()) return;  // not ours (a serial line), or gone already
  Connection& connection = *it->second;
  switch (admission_.on_admitted(connection.id)) {
    case AdmissionControl::Admission::admitted:
      return;
    case AdmissionControl::Admission::refused:
      if (!warned_link_cap_) {
        warned_link_cap_ = true;
        spdlog::warn(
            "backbone: {} links are bound already (max_links): {} closed; further refusals are "
            "only counted",
            admission_.limits().max_links, connection.link->peer_name());
      }
      break;
    case AdmissionControl::Admission::not_pending:
      break;  // timed out or evicted in the meantime: closing already
  }
  connection.link->close();
}

asio::awaitable<void> TcpServer::accept_loop() {
  boost::system::error_code ec;
  acceptor_.non_blocking(true, ec);
  while (!stopped_ && !ec) {
    // Wait until connections are queued, then take every one queued (up to a batch) at once: a
    // real peer queued behind a flood must not wait a scheduler turn per connection ahead of it.
    std::tie(ec) = co_await acceptor_.async_wait(tcp::acceptor::wait_read, kNoError);
    for (int taken = 0; !stopped_ && !ec && taken < kAcceptBatch; ++taken) {
      tcp::socket socket(executor_);
      tcp::endpoint peer;  // from accept itself: no getpeername per connection
      acceptor_.accept(socket, peer, ec);
      if (ec == asio::error::would_block || ec == asio::error::try_again) {
        ec = {};
        break;
      }
      if (!ec) take(std::move(socket), peer);
    }
    if (stopped_) break;
    if (ec) {
      ++counters_.accept_errors;
      spdlog::warn("backbone: accept on port {} failed: {}", port_, ec.message());
      retry_timer_.expires_after(options_.accept_retry_delay);
      co_await retry_timer_.async_wait(kNoError);
      ec = {};
    }
  }
  on_accepted_ = nullptr;  // drops anything the handler captured, e.g. the server itself
}

void TcpServer::take(tcp::socket socket, const tcp::endpoint& peer) {
  ++counters_.accepted;
  const ConnectionId id = next_id_ + 1;
  // A real peer speaks at once (TLS ClientHello, session hello): usually its bytes are here
  // before we accept it, which protects it from eviction by connections that only hold a slot.
  boost::system::error_code ignored;
  const bool talking = socket.available(ignored) > 0;
  const auto accepted = admission_.on_accepted_from(source_of(peer), id, Clock::now(), talking);
  if (accepted.refused) {
    // Closed before anything was read or allocated for it: a source that keeps failing costs
    // an accept and a close, never a handshake or a pending slot.
    if (!warned_source_) {
      warned_source_ = true;
      spdlog::warn(
          "backbone: {} keeps failing handshakes on port {}: its connections are closed at "
          "accept until it has been quiet a while; further refusals are only counted",
          peer.address().to_string(), port_);
    }
    socket.close(ignored);
    return;
  }
  next_id_ = id;
  auto connection = std::make_shared<Connection>();
  connection->id = id;
  connections_.emplace(connection->id, connection);
  if (const auto evicted = accepted.evicted) {
    if (!warned_evicted_) {
      warned_evicted_ = true;
      spdlog::warn(
          "backbone: {} handshakes in progress on port {} (max_pending_handshakes): a pending "
          "one (silent ones first) is closed for each new connection; further evictions are "
          "only counted",
          admission_.limits().max_pending_handshakes, port_);
    }
    end_connection(*evicted);
  }
  arm_deadline();
  // Each connection waits and upgrades in its own coroutine, so a slow or silent peer never holds
  // up the accept loop; the coroutine runs on the handshakes' queue, so a flood of them never
  // holds up the established links either (the link it hands over runs on the loop's own
  // executor). The connection outlives the coroutine (its signal is bound to it): the last
  // reference goes on a later turn of the loop.
  auto slot = connection->cancel.slot();
  coro::spawn_owned(handshakes_->executor(), serve(connection, std::move(socket), talking), slot,
                    [self = shared_from_this(), connection](const std::string& failure) mutable {
                      self->connection_done(*connection, failure);
                      asio::post(self->executor_, [c = std::move(connection)] {});
                    });
}

asio::awaitable<UpgradeResult> TcpServer::upgrade(tcp::socket socket) {
  if (!options_.upgrade) {
    co_return UpgradeResult{StreamLink::create(std::move(socket), options_.link), {}};
  }
  // The upgrade is code of its own (TLS): whatever it throws, cancellation included (a co_await
  // after the deadline cancelled it throws operation_aborted), fails this one connection only.
  try {
    co_return co_await options_.upgrade(std::move(socket), options_.link);
  } catch (const boost::system::system_error& e) {
    co_return UpgradeResult{nullptr, e.code()};
  } catch (const std::system_error& e) {
    co_return UpgradeResult{nullptr, e.code()};
  } catch (const std::exception&) {
    co_return UpgradeResult{nullptr, std::make_error_code(std::errc::protocol_error)};
  }
}

asio::awaitable<void> TcpServer::serve(std::shared_ptr<Connection> connection, tcp::socket socket,
                                       bool talking) {
  // Evicted before it ran: the cancellation found nothing to cancel yet.
  if (stopped_ || !admission_.is_pending(connection->id)) co_return;
  // Under admission limits, a silent connection costs only its socket until its peer says
  // something: no link, no session, no TLS state (cancelled when evicted or at the deadline).
  // Unlimited (tests, benches), the link comes at once, for protocols where the server speaks.
  const bool limited = admission_.limits().max_pending_handshakes !=
                       AdmissionLimits::unlimited().max_pending_handshakes;
  if (!talking && limited) {
    auto [ec] = co_await socket.async_wait(tcp::socket::wait_read, kNoError);
    if (ec || stopped_ || !admission_.is_pending(connection->id)) co_return;
    boost::system::error_code ignored;
    if (socket.available(ignored) == 0) {  // the peer left without a word
      ++counters_.left_silent;
      co_return;
    }
    admission_.on_talking(connection->id);
  }
  UpgradeResult result = co_await upgrade(std::move(socket));
  const bool ended = stopped_ || !admission_.is_pending(connection->id);
  if (!result.link || ended) {
    ++counters_.upgrade_failures;
    if (result.link) result.link->close();
    spdlog::debug("backbone: connection {} ended before its handshake completed: {}",
                  connection->id, result.error ? result.error.message() : "evicted or timed out");
    co_return;
  }
  std::shared_ptr<StreamLink> link = std::move(result.link);
  admission_.on_upgraded(connection->id, Clock::now());
  connection->link = link;
  spdlog::debug("backbone: accepted {}", link->peer_name());
  if (on_accepted_) on_accepted_(link);
  if (!link->started()) {
    spdlog::error("backbone: accepted handler did not start the link");
    link->close();
  }
  co_await link->async_wait_closed();
}

void TcpServer::connection_done(const Connection& connection, const std::string& failure) {
  admission_.on_closed(connection.id, Clock::now());
  connections_.erase(connection.id);
  if (admission_.pending() == 0) release_freed_memory();
  if (failure.empty()) return;
  if (connection.cancelled) {
    // A coroutine cancelled before it ran ends with operation_aborted at its first co_await.
    spdlog::debug("backbone: connection {} cancelled: {}", connection.id, failure);
    return;
  }
  // The handler threw: a bug, which stops the server as one in the accept loop would.
  spdlog::error("backbone: server on port {} stopped: {}", port_, failure);
  stop();
  on_accepted_ = nullptr;
}

asio::awaitable<void> TcpServer::deadline_loop() {
  while (!stopped_) {
    co_await deadline_timer_.async_wait(kNoError);  // also wakes when arm_deadline() moves it
    if (stopped_) break;
    const auto expired = admission_.expired(Clock::now());
    if (!expired.empty() && !warned_timeout_) {
      warned_timeout_ = true;
      spdlog::warn(
          "backbone: a connection on port {} did not complete its handshake within {} ms: "
          "closed; further timeouts are only counted",
          port_, admission_.limits().handshake_timeout.count());
    }
    for (ConnectionId id : expired) end_connection(id);
    deadline_timer_.expires_at(admission_.next_deadline().value_or(Clock::time_point::max()));
  }
}

void TcpServer::release_freed_memory() {
  // Only after many connections: one trim walks the whole heap.
  if (next_id_ - connections_at_last_trim_ < kConnectionsBetweenTrims) return;
  connections_at_last_trim_ = next_id_;
  ++counters_.heap_trims;
#if defined(__GLIBC__)
  ::malloc_trim(0);
#endif
}

void TcpServer::arm_deadline() {
  const auto next = admission_.next_deadline();
  if (next && *next < deadline_timer_.expiry()) deadline_timer_.expires_at(*next);
}

void TcpServer::end_connection(ConnectionId id) {
  const auto it = connections_.find(id);
  if (it == connections_.end()) return;
  cancel(*it->second);
}

}  // namespace canbridge::backbone
