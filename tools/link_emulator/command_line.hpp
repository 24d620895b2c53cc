// The link emulator's command line and the lines it prints, shared by the program and the tests
// that drive it (so both agree on one format).
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "logging/log_setup.hpp"
#include "tools/link_emulator/cut_schedule.hpp"
#include "tools/link_emulator/impairment.hpp"

namespace canbridge::emulator {

// One end of the emulated link.
struct EndpointSpec {
  enum class Kind { tcp_listen, tcp_connect, pty };
  Kind kind = Kind::tcp_listen;
  std::string host;  // tcp-*: name or address (IPv6 without brackets)
  std::uint16_t port = 0;
  std::string path;  // pty: where the symlink to the slave device goes
};

// "tcp-listen:HOST:PORT" (port 0 = any free port), "tcp-connect:HOST:PORT", "pty:PATH". On a
// syntax error: nullopt and a message in `error`.
std::optional<EndpointSpec> parse_endpoint(std::string_view text, std::string& error);
// The spec's text form ("[::1]" style brackets for IPv6 hosts).
std::string to_string(const EndpointSpec& spec);

struct EmulatorOptions {
  EndpointSpec a;
  EndpointSpec b;
  // Applies to both directions; each direction's seed is derived from `seed`.
  ImpairmentOptions line;
  std::uint64_t seed = 1;
  CutSchedule cuts;
  // What a cut does to TCP connections. close: they end and new ones are refused (a reset link,
  // seen at once). silent: they stay open and nothing moves either way, new ones wait unserved
  // (a blackholed route: each end learns only from its own silence; what was sent before or
  // during the cut arrives afterwards if the receiving end still holds its connection).
  enum class CutMode { close, silent };
  CutMode cut_mode = CutMode::close;
  std::chrono::seconds stats_interval{0};  // 0 = only the final stats line

  ImpairmentOptions a_to_b() const;
  ImpairmentOptions b_to_a() const;
};

struct CommandLine {
  std::optional<EmulatorOptions> options;  // set when the arguments are valid
  bool help = false;                       // --help: print kUsage, exit 0
  bool version = false;                    // --version: print the version, exit 0
  std::string error;                       // otherwise: what is wrong (exit 2)
  // -v (debug), -vv (trace), --log-level; unset: info.
  std::optional<std::string> log_level;
  logging::LogFormat log_format = logging::LogFormat::automatic;
};

// argv without the program name.
CommandLine parse_command_line(const std::vector<std::string>& args);

extern const char* const kUsage;

// The single line printed once every endpoint is in place, e.g.
//   link-emulator: ready a=tcp-listen:127.0.0.1:41234 b=pty:/tmp/x/surface->/dev/pts/5
// `a` and `b` are the resolved endpoints: listening ports as bound, ptys as "PATH->DEVICE".
std::string format_ready_line(std::string_view a, std::string_view b);

struct ReadyLine {
  std::string a;  // as formatted, e.g. "tcp-listen:127.0.0.1:41234"
  std::string b;
};
// Finds the ready line in a program's output (tests); nullopt when it is not there (yet).
std::optional<ReadyLine> find_ready_line(std::string_view output);
// The port of a resolved "tcp-listen:HOST:PORT" or "tcp-connect:HOST:PORT" endpoint.
std::optional<std::uint16_t> endpoint_port(std::string_view resolved);
// The slave device of a resolved "pty:PATH->DEVICE" endpoint.
std::optional<std::string> endpoint_pty_device(std::string_view resolved);

// "link-emulator: <label> a->b in=.. out=.. flipped=.. lost=.. cut_dropped=.. disconnect_dropped=..
// b->a in=.. ..." on one line.
std::string format_stats(std::string_view label, const ImpairmentCounters& a_to_b,
                         const ImpairmentCounters& b_to_a);

}  // namespace canbridge::emulator
