// The surface's CiA 309-3 ASCII command endpoint (docs/remote-access.md): a Unix socket (and, if
// configured, a loopback TCP port) where operators and tools send text commands that it turns
// into RemoteAccess calls, answering each client's commands in order.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "bridge/command_endpoint_options.hpp"
#include "bridge/remote_access.hpp"

namespace canbridge::bridge {

struct CommandEndpointCounters {
  std::uint64_t clients = 0;          // connections served (Unix and TCP)
  std::uint64_t clients_refused = 0;  // beyond max_clients
  std::uint64_t auth_failures = 0;    // TCP: no or a wrong token
  std::uint64_t commands = 0;         // lines with a command
  std::uint64_t errors = 0;           // `ERROR:` responses (refusals included)
  std::uint64_t refused = 0;          // `ERROR:403`: not allowed for the client's role
  std::uint64_t monitor_dropped = 0;  // frame lines a slow monitor client never got
  std::size_t sessions = 0;           // connected now
};

// Not thread-safe: call every member on the executor's thread. `remote` must outlive the
// endpoint. Its coroutines hold only the endpoint's shared state, so destroying it (after
// stop()) while they wind down is safe.
class CommandEndpoint {
 public:
  CommandEndpoint(boost::asio::any_io_executor executor, CommandEndpointOptions options,
                  RemoteAccess& remote);
  ~CommandEndpoint();
  CommandEndpoint(const CommandEndpoint&) = delete;
  CommandEndpoint& operator=(const CommandEndpoint&) = delete;

  // Listens on the Unix socket (mode 0660; a stale socket file is replaced, any other file is
  // left alone and refused) and on TCP when tcp_port is set (loopback addresses only). Throws
  // std::runtime_error saying what is wrong: a startup error. Call once.
  void start();
  // Closes the listeners and every client (their pending requests are cancelled) at once; the
  // coroutines end on their next turn. Removes the socket file it made. Idempotent.
  void stop();

  // Answers `stats` with `json()` as one line ("[seq] {...}", then "[seq] OK"); without it,
  // `stats` is refused as not supported.
  void serve_stats(std::function<std::string()> json);

  // The bound TCP port (0 without TCP).
  std::uint16_t tcp_port() const;
  CommandEndpointCounters counters() const;

  struct Core;  // the shared state every coroutine holds

 private:
  std::shared_ptr<Core> core_;
};

}  // namespace canbridge::bridge
