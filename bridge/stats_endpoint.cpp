#include "bridge/stats_endpoint.hpp"

#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/local/stream_protocol.hpp>
#include <boost/asio/read_until.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/streambuf.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <cerrno>
#include <cstring>

#include "bridge/endpoint_server.hpp"
#include "canopen/ascii_command.hpp"
#include "canopen/ascii_response.hpp"
#include "coro/no_error.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;
using Local = asio::local::stream_protocol;
using coro::kNoError;
constexpr std::size_t kMaxLine = 256;  // `[<seq>] stats` and a comment fit many times over

struct StatsEndpoint::Core : std::enable_shared_from_this<StatsEndpoint::Core> {
  using Server = EndpointServer<Local::acceptor, Local::socket>;

  Core(asio::any_io_executor ex, StatsEndpointOptions o, std::function<std::string()> j)
      : executor(std::move(ex)), options(std::move(o)), json(std::move(j)) {}

  // One client: a line in, its answer out, one at a time; closed on an idle deadline.
  static asio::awaitable<void> serve(std::shared_ptr<Core> self,
                                     std::shared_ptr<Local::socket> socket) {
    if (!self) co_return;
    asio::streambuf buffer(kMaxLine);
    asio::steady_timer deadline(self->executor);
    while (self->server->open() && socket->is_open()) {
      deadline.expires_after(self->options.idle_timeout);
      deadline.async_wait([socket](boost::system::error_code ec) {
        if (!ec) {
          boost::system::error_code ignored;
          socket->close(ignored);
        }
      });
      auto [ec, n] = co_await asio::async_read_until(*socket, buffer, '\n', kNoError);
      deadline.cancel();
      if (ec || !self->server->open()) break;  // closed, idle, stopped, or a line too long
      std::string line(asio::buffers_begin(buffer.data()),
                       asio::buffers_begin(buffer.data()) + static_cast<std::ptrdiff_t>(n - 1));
      buffer.consume(n);
      const canopen::AsciiParse parse = canopen::parse_ascii_command(line);
      const auto seq = parse.command.sequence;
      std::string answer;
      if (!parse.ok()) {
        answer = canopen::ascii_error(seq, *parse.error, parse.detail);
      } else if (parse.command.verb == canopen::AsciiVerb::none) {
        continue;
      } else if (parse.command.verb != canopen::AsciiVerb::stats) {
        answer = canopen::ascii_error(seq, canopen::AsciiError::request_not_supported,
                                      "the gateway answers stats only");
      } else {
        answer = canopen::ascii_line(seq, self->json()) + canopen::ascii_ok(seq);
      }
      auto [write_ec, written] =
          co_await asio::async_write(*socket, asio::buffer(answer), kNoError);
      (void)written;
      if (write_ec) break;
    }
  }

  void start() {
    const std::string& path = options.unix_socket;
    server = std::make_shared<Server>(
        executor, "stats endpoint", options.max_clients,
        [weak = weak_from_this()](std::shared_ptr<Local::socket> socket) {
          return serve(weak.lock(), std::move(socket));
        },
        [](Local::socket& socket) {
          const std::string full = canopen::ascii_error(
              std::nullopt, canopen::AsciiError::internal_state, "too many clients");
          boost::system::error_code ignored;
          asio::write(socket, asio::buffer(full), ignored);  // a few bytes on a fresh socket
        });
    Local::acceptor& acceptor = server->acceptor();
    struct stat st {};
    boost::system::error_code ec;
    if (::lstat(path.c_str(), &st) == 0) {
      if (!S_ISSOCK(st.st_mode)) {
        throw std::runtime_error("stats endpoint: " + path +
                                 " exists and is not a socket; refusing to replace it");
      }
      Local::socket probe(executor);
      probe.connect(Local::endpoint(path), ec);
      if (!ec) throw std::runtime_error("stats endpoint: another process serves " + path);
      ::unlink(path.c_str());
    }
    acceptor.open(Local(), ec);
    if (!ec) acceptor.bind(Local::endpoint(path), ec);
    if (ec) throw std::runtime_error("stats endpoint: cannot bind " + path + ": " + ec.message());
    made_socket = true;
    if (::chmod(path.c_str(), 0660) != 0) {
      throw std::runtime_error("stats endpoint: cannot chmod " + path + ": " +
                               std::strerror(errno));
    }
    acceptor.listen(asio::socket_base::max_listen_connections, ec);
    if (ec)
      throw std::runtime_error("stats endpoint: cannot listen on " + path + ": " + ec.message());
    server->start();
    spdlog::info("stats endpoint: listening on {}", path);
  }

  void stop() {
    if (server) server->stop();
    if (made_socket) ::unlink(options.unix_socket.c_str());
    made_socket = false;
  }

  asio::any_io_executor executor;
  StatsEndpointOptions options;
  std::function<std::string()> json;
  std::shared_ptr<Server> server;
  bool made_socket = false;
};

StatsEndpoint::StatsEndpoint(asio::any_io_executor executor, StatsEndpointOptions options,
                             std::function<std::string()> json)
    : core_(std::make_shared<Core>(std::move(executor), std::move(options), std::move(json))) {}

StatsEndpoint::~StatsEndpoint() {
  core_->stop();
}

void StatsEndpoint::start() {
  core_->start();
}

void StatsEndpoint::stop() {
  core_->stop();
}

}  // namespace canbridge::bridge
