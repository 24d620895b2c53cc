#include "bridge/metrics_endpoint.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/detached.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/string_body.hpp>
#include <boost/beast/http/write.hpp>
#include <list>

#include "coro/no_error.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;
using coro::kNoError;
constexpr std::size_t kMaxRequestBytes = 8192;  // a GET and its headers; anything larger: closed

struct MetricsEndpoint::Core : std::enable_shared_from_this<MetricsEndpoint::Core> {
  Core(asio::any_io_executor ex, MetricsEndpointOptions o, std::function<std::string()> e)
      : executor(std::move(ex)),
        options(std::move(o)),
        exposition(std::move(e)),
        acceptor(executor) {}

  asio::awaitable<void> accept() {
    auto self = shared_from_this();
    while (open) {
      auto [ec, socket] = co_await acceptor.async_accept(kNoError);
      if (!open) break;
      if (ec) {
        asio::steady_timer pause(executor, std::chrono::milliseconds(100));
        co_await pause.async_wait(kNoError);
        continue;
      }
      if (connections.size() >= options.max_connections) continue;  // closed as it goes
      connections.push_back(std::make_shared<beast::tcp_stream>(std::move(socket)));
      asio::co_spawn(executor, serve(self, connections.back()), asio::detached);
    }
  }

  http::response<http::string_body> answer(const http::request<http::string_body>& request) {
    http::response<http::string_body> response;
    response.version(request.version());
    response.keep_alive(request.keep_alive());
    const bool metrics = request.target() == "/metrics" && (request.method() == http::verb::get ||
                                                            request.method() == http::verb::head);
    if (metrics) {
      response.result(http::status::ok);
      response.set(http::field::content_type, "text/plain; version=0.0.4; charset=utf-8");
      if (request.method() == http::verb::get)
        response.body() = exposition();
      else
        response.content_length(exposition().size());
    } else {
      response.result(http::status::not_found);
      response.set(http::field::content_type, "text/plain; charset=utf-8");
      response.body() = "not found: only GET /metrics is served\n";
    }
    if (request.method() != http::verb::head) response.prepare_payload();
    return response;
  }

  static asio::awaitable<void> serve(std::shared_ptr<Core> self,
                                     std::shared_ptr<beast::tcp_stream> stream) {
    beast::flat_buffer buffer(kMaxRequestBytes);
    while (self->open) {
      http::request_parser<http::string_body> parser;
      parser.header_limit(kMaxRequestBytes);
      parser.body_limit(kMaxRequestBytes);
      stream->expires_after(self->options.read_timeout);
      auto [ec, n] = co_await http::async_read(*stream, buffer, parser, kNoError);
      (void)n;
      if (ec || !self->open) break;  // closed, timed out, malformed or too large
      const http::request<http::string_body>& request = parser.get();
      http::response<http::string_body> response = self->answer(request);
      stream->expires_after(self->options.read_timeout);  // a reader too slow for the answer
      auto [write_ec, written] = co_await http::async_write(*stream, response, kNoError);
      (void)written;
      if (write_ec || !response.keep_alive()) break;
    }
    beast::error_code ignored;
    stream->socket().shutdown(tcp::socket::shutdown_both, ignored);
    stream->close();
    self->connections.remove(stream);
  }

  void start() {
    boost::system::error_code ec;
    const auto address = asio::ip::make_address(options.address, ec);
    if (ec) throw std::runtime_error("metrics: " + options.address + " is not an IP address");
    if (!address.is_loopback()) {
      throw std::runtime_error("metrics: " + options.address +
                               " is not a loopback address; the metrics endpoint only listens "
                               "on loopback");
    }
    const tcp::endpoint endpoint(address, options.port);
    acceptor.open(endpoint.protocol(), ec);
    if (!ec) acceptor.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor.bind(endpoint, ec);
    if (!ec) acceptor.listen(asio::socket_base::max_listen_connections, ec);
    if (!ec) port = acceptor.local_endpoint(ec).port();
    if (ec) {
      throw std::runtime_error("metrics: cannot listen on " + options.address + ":" +
                               std::to_string(options.port) + ": " + ec.message());
    }
    open = true;
    asio::co_spawn(executor, accept(), asio::detached);
    spdlog::info("metrics: serving http://{}:{}/metrics", options.address, port);
  }

  void stop() {
    open = false;
    boost::system::error_code ignored;
    acceptor.close(ignored);
    for (auto& c : connections) c->socket().close(ignored);
  }

  asio::any_io_executor executor;
  MetricsEndpointOptions options;
  std::function<std::string()> exposition;
  tcp::acceptor acceptor;
  std::list<std::shared_ptr<beast::tcp_stream>> connections;
  std::uint16_t port = 0;
  bool open = false;
};

MetricsEndpoint::MetricsEndpoint(asio::any_io_executor executor, MetricsEndpointOptions options,
                                 std::function<std::string()> exposition)
    : core_(
          std::make_shared<Core>(std::move(executor), std::move(options), std::move(exposition))) {}

MetricsEndpoint::~MetricsEndpoint() {
  core_->stop();
}

void MetricsEndpoint::start() {
  core_->start();
}

void MetricsEndpoint::stop() {
  core_->stop();
}

std::uint16_t MetricsEndpoint::port() const {
  return core_->port;
}

}  // namespace canbridge::bridge
