#include "backbone/serial_client.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/serial_port.hpp>
#include <boost/asio/use_awaitable.hpp>

#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::backbone {

namespace asio = boost::asio;
using coro::kNoError;

std::error_code open_serial_port(asio::serial_port& port, const SerialOptions& options) {
  boost::system::error_code ec;
  port.open(options.device, ec);  // asio puts the line in raw mode
  if (ec) return ec;
  using base = asio::serial_port_base;
  port.set_option(base::baud_rate(options.baud), ec);
  if (!ec) port.set_option(base::character_size(8), ec);
  if (!ec) port.set_option(base::parity(base::parity::none), ec);
  if (!ec) port.set_option(base::stop_bits(base::stop_bits::one), ec);
  if (!ec) {
    port.set_option(base::flow_control(options.hardware_flow_control ? base::flow_control::hardware
                                                                     : base::flow_control::none),
                    ec);
  }
  if (ec) {
    boost::system::error_code ignored;
    port.close(ignored);
  }
  return ec;
}

std::shared_ptr<SerialClient> SerialClient::create(asio::any_io_executor executor,
                                                   SerialOptions options) {
  return std::shared_ptr<SerialClient>(new SerialClient(std::move(executor), std::move(options)));
}

SerialClient::SerialClient(asio::any_io_executor executor, SerialOptions options)
    : executor_(std::move(executor)),
      options_(std::move(options)),
      backoff_timer_(executor_),
      backoff_(options_.backoff_min, options_.backoff_max) {}

SerialClient::~SerialClient() = default;

void SerialClient::start(ConnectedHandler on_connected) {
  if (started_ || stopped_) return;
  started_ = true;
  on_connected_ = std::move(on_connected);
  // The loop holds the client alive until stop() lets it finish; if it fails (a handler threw),
  // the client says why and stops rather than leave a line that is never reopened.
  coro::spawn_owned(executor_, run(), [self = shared_from_this()](const std::string& failure) {
    if (failure.empty()) return;
    spdlog::error("backbone: serial line {} stopped: {}", self->options_.device, failure);
    self->stop();
    self->on_connected_ = nullptr;
  });
}

void SerialClient::stop() {
  if (stopped_) return;
  stopped_ = true;
  backoff_timer_.cancel();
  if (link_) link_->close();
}

asio::awaitable<void> SerialClient::run() {
  while (!stopped_) {
    asio::serial_port port(executor_);
    if (const std::error_code ec = open_serial_port(port, options_)) {
      ++counters_.open_failures;
      if (!failing_) {
        spdlog::warn("backbone: cannot open serial line {}: {} (retrying up to every {} ms)",
                     options_.device, ec.message(), backoff_.max().count());
      }
      failing_ = true;
    } else {
      ++counters_.opens;
      failing_ = false;
      spdlog::info("backbone: serial line {} open at {} bit/s", options_.device, options_.baud);
      auto link = StreamLink::create(std::move(port), options_.device, options_.link);
      link_ = link;
      if (on_connected_) on_connected_(link);
      if (!link->started()) link->close();
      const std::error_code reason = co_await link->async_wait_closed();
      link_.reset();
      if (stopped_) break;
      if (reason == make_error_code(errc::refused_by_peer)) {
        // Refused again until a configuration changes: wait longer each time (TcpClient too).
        spdlog::debug("backbone: refused over serial line {}: next attempt in {} ms",
                      options_.device, backoff_.peek().count());
      } else {
        spdlog::info("backbone: serial link {} ended: {}", options_.device, reason.message());
        backoff_.reset();
      }
    }
    // A line that ends at once (peer gone, device unplugged) must not become a busy loop.
    backoff_timer_.expires_after(backoff_.next());
    co_await backoff_timer_.async_wait(kNoError);
  }
  on_connected_ = nullptr;
}

}  // namespace canbridge::backbone
