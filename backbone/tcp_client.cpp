#include "backbone/tcp_client.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/bind_cancellation_slot.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/connect.hpp>
#include <boost/asio/use_awaitable.hpp>

#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
using asio::ip::tcp;

namespace {
using coro::kNoError;
}

std::shared_ptr<TcpClient> TcpClient::create(asio::any_io_executor executor, std::string host,
                                             std::uint16_t port, ClientOptions options) {
  return std::shared_ptr<TcpClient>(
      new TcpClient(std::move(executor), std::move(host), port, options));
}

TcpClient::TcpClient(asio::any_io_executor executor, std::string host, std::uint16_t port,
                     ClientOptions options)
    : executor_(std::move(executor)),
      host_(std::move(host)),
      port_(port),
      options_(options),
      resolver_(executor_),
      socket_(executor_),
      deadline_(executor_),
      backoff_timer_(executor_),
      backoff_(options.backoff_min, options.backoff_max) {}

TcpClient::~TcpClient() = default;

void TcpClient::start(ConnectedHandler on_connected) {
  if (started_ || stopped_) return;
  started_ = true;
  on_connected_ = std::move(on_connected);
  // The loop holds the client alive until stop() lets it finish; if it fails (a handler threw),
  // the client says why and stops rather than leave a process that never reconnects.
  coro::spawn_owned(executor_, run(), [self = shared_from_this()](const std::string& failure) {
    if (failure.empty()) return;
    spdlog::error("backbone: client for {}:{} stopped: {}", self->host_, self->port_, failure);
    self->stop();
    self->on_connected_ = nullptr;
  });
}

void TcpClient::stop() {
  if (stopped_) return;
  stopped_ = true;
  resolver_.cancel();
  boost::system::error_code ignored;
  socket_.close(ignored);
  deadline_.cancel();
  backoff_timer_.cancel();
  upgrade_cancel_.emit(asio::cancellation_type::terminal);
  if (link_) link_->close();
}

asio::awaitable<void> TcpClient::run() {
  while (!stopped_) {
    const std::error_code ec = co_await connect_once();
    if (stopped_) break;
    if (ec) {
      ++counters_.connect_failures;
      if (!failing_) {
        spdlog::warn("backbone: cannot connect to {}:{}: {} (retrying up to every {} ms)", host_,
                     port_, ec.message(), backoff_.max().count());
      } else {
        spdlog::debug("backbone: connect to {}:{} failed: {}", host_, port_, ec.message());
      }
      failing_ = true;
      co_await back_off();
      continue;
    }

    ++counters_.connects;
    failing_ = false;
    auto link =
        upgraded_ ? std::move(upgraded_) : StreamLink::create(std::move(socket_), options_.link);
    upgraded_.reset();
    socket_ = tcp::socket(executor_);
    // While refused, each attempt connects: the refusal (logged once) is the news, not that.
    spdlog::log(refused_ ? spdlog::level::debug : spdlog::level::info,
                "backbone: connected to {}:{}", host_, port_);
    link_ = link;
    if (on_connected_) on_connected_(link);
    if (!link->started()) {
      spdlog::error("backbone: connected handler did not start the link to {}:{}", host_, port_);
      link->close();
    }
    const std::error_code reason = co_await link->async_wait_closed();
    link_.reset();
    if (stopped_) break;
    refused_ = reason == make_error_code(errc::refused_by_peer);
    if (refused_) {
      // The peer will refuse the same hello again until someone fixes a configuration: each
      // retry waits longer, up to backoff_max. The session logged why (once per reason).
      spdlog::debug("backbone: refused by {}:{}: next attempt in {} ms", host_, port_,
                    backoff_.peek().count());
    } else {
      spdlog::info("backbone: link to {}:{} lost: {}", host_, port_, reason.message());
      backoff_.reset();
    }
    // Even after a good connection, wait backoff_min: a peer that accepts and drops at once must
    // not turn this into a busy loop.
    co_await back_off();
  }
  on_connected_ = nullptr;  // drops anything the handler captured, e.g. the client itself
}

asio::awaitable<std::error_code> TcpClient::connect_once() {
  // One deadline for resolve + connect: on expiry it aborts whichever is pending.
  const std::uint64_t attempt = ++attempt_;
  deadline_.expires_after(options_.connect_timeout);
  deadline_.async_wait([weak = weak_from_this(), attempt](boost::system::error_code ec) {
    auto self = weak.lock();
    if (ec || !self || self->attempt_ != attempt) return;
    self->resolver_.cancel();
    boost::system::error_code ignored;
    self->socket_.close(ignored);
    self->upgrade_cancel_.emit(asio::cancellation_type::terminal);
  });

  auto [resolve_ec, endpoints] = co_await resolver_.async_resolve(
      host_, std::to_string(port_), tcp::resolver::numeric_service, kNoError);
  std::error_code result = resolve_ec;
  if (!resolve_ec && !stopped_) {
    socket_ = tcp::socket(executor_);
    ++counters_.attempts;
    auto [connect_ec, endpoint] = co_await asio::async_connect(socket_, endpoints, kNoError);
    result = connect_ec;
    if (!result && options_.upgrade && !stopped_) result = co_await upgrade();
  }
  ++attempt_;  // a deadline expiry already queued must not touch the next attempt's socket
  deadline_.cancel();
  if (result == std::errc::operation_canceled && !stopped_) {
    result = std::make_error_code(std::errc::timed_out);
  }
  co_return result;
}

asio::awaitable<std::error_code> TcpClient::upgrade() {
  // Spawned so that the deadline and stop() can cancel it through upgrade_cancel_, whatever the
  // upgrade awaits inside.
  auto [failure, result] =
      co_await asio::co_spawn(executor_, options_.upgrade(std::move(socket_), options_.link),
                              asio::bind_cancellation_slot(upgrade_cancel_.slot(), kNoError));
  upgrade_cancel_.slot().clear();
  socket_ = tcp::socket(executor_);
  if (failure) co_return std::make_error_code(std::errc::protocol_error);  // it threw
  if (!result.link && !result.error) co_return std::make_error_code(std::errc::protocol_error);
  if (result.error) co_return result.error;
  upgraded_ = std::move(result.link);
  co_return std::error_code{};
}

asio::awaitable<void> TcpClient::back_off() {
  backoff_timer_.expires_after(backoff_.next());
  co_await backoff_timer_.async_wait(kNoError);
}

}  // namespace canbridge::backbone
