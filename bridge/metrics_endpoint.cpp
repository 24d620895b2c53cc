#include "bridge/metrics_endpoint.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/string_body.hpp>
#include <boost/beast/http/write.hpp>

#include "bridge/endpoint_server.hpp"
#include "coro/no_error.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;
using coro::kNoError;
constexpr std::size_t kMaxRequestBytes = 8192;  // a GET and its headers; anything larger: closed

struct MetricsEndpoint::Core : std::enable_shared_from_this<MetricsEndpoint::Core> {
  using Server = EndpointServer<tcp::acceptor, beast::tcp_stream>;

  Core(asio::any_io_executor ex, MetricsEndpointOptions o, std::function<std::string()> e)
      : executor(std::move(ex)), options(std::move(o)), exposition(std::move(e)) {}

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
    if (!self) co_return;
    beast::flat_buffer buffer(kMaxRequestBytes);
    while (self->server->open()) {
      http::request_parser<http::string_body> parser;
      parser.header_limit(kMaxRequestBytes);
      parser.body_limit(kMaxRequestBytes);
      stream->expires_after(self->options.read_timeout);
      auto [ec, n] = co_await http::async_read(*stream, buffer, parser, kNoError);
      (void)n;
      if (ec || !self->server->open()) break;  // closed, timed out, malformed or too large
      const http::request<http::string_body>& request = parser.get();
      http::response<http::string_body> response = self->answer(request);
      stream->expires_after(self->options.read_timeout);  // a reader too slow for the answer
      auto [write_ec, written] = co_await http::async_write(*stream, response, kNoError);
      (void)written;
      if (write_ec || !response.keep_alive()) break;
    }
    beast::error_code ignored;
    stream->socket().shutdown(tcp::socket::shutdown_both, ignored);
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
    // Past max_connections a connection is closed as it comes: a scraper retries.
    server =
        std::make_shared<Server>(executor, "metrics", options.max_connections,
                                 [weak = weak_from_this()](std::shared_ptr<beast::tcp_stream> s) {
                                   return serve(weak.lock(), std::move(s));
                                 });
    tcp::acceptor& acceptor = server->acceptor();
    acceptor.open(endpoint.protocol(), ec);
    if (!ec) acceptor.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor.bind(endpoint, ec);
    if (!ec) acceptor.listen(asio::socket_base::max_listen_connections, ec);
    if (!ec) port = acceptor.local_endpoint(ec).port();
    if (ec) {
      throw std::runtime_error("metrics: cannot listen on " + options.address + ":" +
                               std::to_string(options.port) + ": " + ec.message());
    }
    server->start();
    spdlog::info("metrics: serving http://{}:{}/metrics", options.address, port);
  }

  void stop() {
    if (server) server->stop();
  }

  asio::any_io_executor executor;
  MetricsEndpointOptions options;
  std::function<std::string()> exposition;
  std::shared_ptr<Server> server;
  std::uint16_t port = 0;
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
