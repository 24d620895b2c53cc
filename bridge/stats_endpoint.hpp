// The gateway's local statistics endpoint: a Unix socket answering the CiA 309-3 style line
// `[<seq>] stats` with the role's statistics as one JSON line and `[<seq>] OK`, as the surface's
// command endpoint does, so `canbridge stats --endpoint PATH` reads either.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <string>

namespace canbridge::bridge {

struct StatsEndpointOptions {
  std::string unix_socket;  // created mode 0660; a stale socket file is replaced
  std::size_t max_clients = 4;
  // A client that sends no complete line for this long is closed.
  std::chrono::milliseconds idle_timeout{30000};
};

// Not thread-safe: call every member on the executor's thread. Its coroutines hold only the
// shared state, so destroying the endpoint (after stop()) while they wind down is safe.
class StatsEndpoint {
 public:
  StatsEndpoint(boost::asio::any_io_executor executor, StatsEndpointOptions options,
                std::function<std::string()> json);
  ~StatsEndpoint();
  StatsEndpoint(const StatsEndpoint&) = delete;
  StatsEndpoint& operator=(const StatsEndpoint&) = delete;

  // Binds and listens; throws std::runtime_error saying what is wrong (a startup error).
  void start();
  // Closes the listener and every client; removes the socket file. Idempotent.
  void stop();

  struct Core;

 private:
  std::shared_ptr<Core> core_;
};

}  // namespace canbridge::bridge
