// The optional Prometheus endpoint: GET /metrics on a loopback address answers the role's
// statistics in the text exposition format 0.0.4 (Boost.Beast, on the role's event loop).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

namespace canbridge::bridge {

struct MetricsEndpointOptions {
  std::string address = "127.0.0.1";  // loopback only: start() refuses any other
  std::uint16_t port = 9464;          // 0: any free port (tests)
  std::size_t max_connections = 4;    // beyond: accepted and closed at once
  // A connection that does not complete a request within this is closed (slow or idle clients
  // cannot hold a slot).
  std::chrono::milliseconds read_timeout{5000};
};

// Not thread-safe: call every member on the executor's thread. One coroutine per connection,
// one request at a time; rendering runs on the loop between frames, as any other handler.
class MetricsEndpoint {
 public:
  MetricsEndpoint(boost::asio::any_io_executor executor, MetricsEndpointOptions options,
                  std::function<std::string()> exposition);
  ~MetricsEndpoint();
  MetricsEndpoint(const MetricsEndpoint&) = delete;
  MetricsEndpoint& operator=(const MetricsEndpoint&) = delete;

  // Listens; throws std::runtime_error (not loopback, port in use): a startup error.
  void start();
  void stop();                 // closes the listener and every connection; idempotent
  std::uint16_t port() const;  // the bound port

  struct Core;

 private:
  std::shared_ptr<Core> core_;
};

}  // namespace canbridge::bridge
