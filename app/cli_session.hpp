// One client session with the surface's command endpoint for a canbridge subcommand: resolves the
// endpoint (option, surface config, default), connects, authenticates on TCP, and runs numbered
// requests, turning every failure into a printed message and the subcommand's exit code.
#pragma once

#include <chrono>
#include <functional>
#include <iosfwd>
#include <memory>
#include <string>
#include <string_view>

#include "app/cli_endpoint_client.hpp"

namespace canbridge::cli {

inline constexpr const char* kDefaultEndpoint = "/run/canbridge/surface.sock";

// The options every subcommand shares.
struct CommonOptions {
  std::string endpoint;     // PATH or HOST:PORT; empty: from `config`, else kDefaultEndpoint
  std::string token_file;   // TCP: the token sent with `auth`
  std::string config;       // the surface's YAML: command_endpoint.unix_socket
  unsigned net = 0;         // CiA 309-3 network; 0 = the surface's network
  double timeout_s = 30.0;  // longest wait for an answer line
  bool stats = false;       // the command is `stats`: a gateway's file names its stats_endpoint
};

// Where to connect: --endpoint, else the surface config's command_endpoint.unix_socket (for
// `stats`, a gateway config's stats_endpoint), else kDefaultEndpoint. On a config that cannot be
// read returns "" and sets `problem`.
std::string resolve_endpoint(const CommonOptions& options, std::string& problem);

struct Io {
  std::ostream& out;
  std::ostream& err;
  bool terminal = false;  // `out` is a terminal: progress as a bar, not as lines
};

class Session {
 public:
  // Connects (and sends `auth` over TCP). nullptr after printing why; `exit` is then set.
  static std::unique_ptr<Session> open(const CommonOptions& options, Io io, int& exit);

  // Sends "[<seq>] <command>" and reads the answers to it: each line for which `intermediate`
  // returns true is consumed, the first other line is the answer. Returns exit_code::ok with the
  // answer in `answer`, or prints the error / timeout / closed connection and returns its code.
  using LineHandler = std::function<bool(std::string_view rest)>;
  int call(std::string_view command, std::string& answer, const LineHandler& intermediate = {},
           std::chrono::milliseconds timeout = std::chrono::milliseconds(0));

  // The raw connection, for the monitor stream after `monitor` was answered OK.
  EndpointConnection& connection() { return *connection_; }
  std::chrono::milliseconds timeout() const { return timeout_; }
  Io& io() { return io_; }
  // Prints a read failure (timeout, closed) as "canbridge: ..." and returns its exit code.
  int report_read_error(std::error_code ec);

 private:
  Session(std::unique_ptr<EndpointConnection> c, Io io, std::string endpoint,
          std::chrono::milliseconds timeout)
      : connection_(std::move(c)), io_(io), endpoint_(std::move(endpoint)), timeout_(timeout) {}
  std::unique_ptr<EndpointConnection> connection_;
  Io io_;
  std::string endpoint_;
  std::chrono::milliseconds timeout_;
  unsigned next_seq_ = 1;
};

// Connects once a subcommand's arguments are known to be good (a usage error never waits on a
// socket): Session::open with the parsed options.
using Connect = std::function<std::unique_ptr<Session>(int& exit)>;

// A bad argument found after parsing (node out of range, unreadable file): exit code 2.
struct UsageError {
  std::string message;
};

}  // namespace canbridge::cli
