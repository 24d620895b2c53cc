#include "backbone/tcp_server.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/use_awaitable.hpp>

#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
using asio::ip::tcp;

namespace {
constexpr auto kNoError = asio::as_tuple(asio::use_awaitable);
}

std::shared_ptr<TcpServer> TcpServer::create(asio::any_io_executor executor,
                                             ServerOptions options) {
  return std::shared_ptr<TcpServer>(new TcpServer(std::move(executor), options));
}

TcpServer::TcpServer(asio::any_io_executor executor, ServerOptions options)
    : executor_(std::move(executor)),
      options_(options),
      acceptor_(executor_),
      retry_timer_(executor_) {}

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
  if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
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
  // The loop holds the server alive until stop() lets it finish; if it fails (a handler threw),
  // the server says why and stops: its links close, and nothing is left half-listening.
  coro::spawn_owned(
      executor_, accept_loop(), [self = shared_from_this()](const std::string& failure) {
        if (failure.empty()) return;
        spdlog::error("backbone: server on port {} stopped: {}", self->port_, failure);
        self->stop();
        self->on_accepted_ = nullptr;
      });
  return {};
}

void TcpServer::stop() {
  if (stopped_) return;
  stopped_ = true;
  boost::system::error_code ignored;
  acceptor_.close(ignored);
  retry_timer_.cancel();
  for (auto& weak : links_) {
    if (auto link = weak.lock()) link->close();
  }
  links_.clear();
}

std::vector<std::shared_ptr<StreamLink>> TcpServer::links() const {
  std::vector<std::shared_ptr<StreamLink>> live;
  for (const auto& weak : links_) {
    if (auto link = weak.lock(); link && link->is_open()) live.push_back(std::move(link));
  }
  return live;
}

asio::awaitable<void> TcpServer::accept_loop() {
  while (!stopped_) {
    auto [ec, socket] = co_await acceptor_.async_accept(kNoError);
    if (stopped_) break;
    if (ec) {
      ++counters_.accept_errors;
      spdlog::warn("backbone: accept on port {} failed: {}", port_, ec.message());
      retry_timer_.expires_after(options_.accept_retry_delay);
      co_await retry_timer_.async_wait(kNoError);
      continue;
    }
    ++counters_.accepted;
    auto link = StreamLink::create(std::move(socket), options_.link);
    spdlog::info("backbone: accepted {}", link->peer_name());
    std::erase_if(links_, [](const std::weak_ptr<StreamLink>& weak) {
      auto live = weak.lock();
      return !live || !live->is_open();
    });
    links_.push_back(link);
    if (on_accepted_) on_accepted_(link);
    if (!link->started()) {
      spdlog::error("backbone: accepted handler did not start the link");
      link->close();
    }
  }
  on_accepted_ = nullptr;  // drops anything the handler captured, e.g. the server itself
}

}  // namespace canbridge::backbone
