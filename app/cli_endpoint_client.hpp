// A blocking client connection to the surface's command endpoint (docs/remote-access.md): request
// lines out, response lines in, each wait bounded; what the canbridge client subcommands speak.
#pragma once

#include <chrono>
#include <memory>
#include <string>
#include <string_view>
#include <system_error>

namespace canbridge::cli {

// Where the endpoint listens: "HOST:PORT" (the text after the last ':' all digits, no '/') is
// TCP, anything else the path of a Unix socket.
struct EndpointAddress {
  bool tcp = false;
  std::string path;  // Unix socket
  std::string host;  // TCP
  std::string port;
};
EndpointAddress parse_endpoint(std::string_view text);

class EndpointConnection {
 public:
  // Connects at once; on failure `ec` says why (refused, no such file, unknown host, ...).
  static std::unique_ptr<EndpointConnection> open(const EndpointAddress& address,
                                                  std::error_code& ec);
  ~EndpointConnection();
  EndpointConnection(const EndpointConnection&) = delete;
  EndpointConnection& operator=(const EndpointConnection&) = delete;

  // Writes `line` and a LF.
  std::error_code send_line(std::string_view line);
  // The next line without its CR LF. errc::timed_out when none is complete within `timeout`,
  // errc::connection_reset when the endpoint closed, errc::interrupted when a signal arrived
  // (the subcommands stop on SIGINT/SIGTERM that way).
  std::error_code read_line(std::string& line, std::chrono::milliseconds timeout);

 private:
  explicit EndpointConnection(int fd) : fd_(fd) {}
  int fd_ = -1;
  std::string buffer_;  // received bytes not yet returned as lines
};

}  // namespace canbridge::cli
