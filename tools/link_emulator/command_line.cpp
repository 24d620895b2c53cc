#include "tools/link_emulator/command_line.hpp"

#include <CLI/CLI.hpp>
#include <charconv>
#include <cmath>
#include <limits>
#include <map>
#include <stdexcept>

#include "logging/command_line_common.hpp"
#include "tools/link_emulator/seeded_random.hpp"

namespace canbridge::emulator {

const char* const kUsage = R"(usage: canbridge-link-emulator --a SPEC --b SPEC [options]
  Passes a byte stream between endpoints A and B like a slow, noisy wireline (deterministic
  for a seed). Bytes A->B and B->A each pass their own impairment with the same options.
endpoints (SPEC):
  tcp-listen:HOST:PORT    accept one connection at a time (port 0 = any free port); a new
                          connection replaces the old one
  tcp-connect:HOST:PORT   connect when the other side is connected (at once when the other
                          side is a pty); reconnect
  pty:PATH                a pseudo-terminal in raw mode; PATH becomes a symlink to its device
line:
  --baud N                line rate in bits/s (0 = unlimited, the default)
  --bits-per-byte N       bits per byte on the line (default 10, as 8N1 serial)
  --latency-ms X          fixed one-way delay
  --jitter-ms X           extra delay, uniform in [0, X] per chunk; never reorders
  --ber X                 bit error rate: each data bit flipped with probability X
  --loss X                each byte lost with probability X
  --buffer-bytes N        bytes held per direction before reading stops (default 1048576)
  --seed N                seed of every random choice (default 1)
cuts (the wire breaks: TCP connections close and are refused, pty bytes are discarded):
  --cuts N --cut-ms D[:D1] --cut-window-s S0:S1 [--cut-gap-ms G]
                          N cuts of D ms (or uniform in D..D1) at random times inside
                          [S0, S1] s after start, at least G ms apart
  --cut-at T+D            a cut at T s for D s (repeatable; not with --cuts)
  --cut-mode close|silent close (default) as above; silent: TCP connections stay open and
                          nothing moves on them until the cut ends (a blackholed route), new
                          ones wait unserved; pty bytes are discarded as with close
output:
  --stats-seconds N       a stats line every N s (default 0: only at exit)
  -v, --verbose           more log on stderr: -v debug, -vv trace (default info)
  --log-level LEVEL       trace|debug|info|warn|error|off
  --log-format FORMAT     auto|text|journal: journal = sd-daemon priority prefixes, no
                          timestamps; auto picks journal when stderr is the journal
  --help, --version
options take their value as "--baud 9600" or "--baud=9600", in any order.
prints "link-emulator: ready a=... b=..." once listening; SIGINT/SIGTERM print a final stats
line and exit 0; bad arguments exit 2.
)";

namespace {

using std::chrono::nanoseconds;

// Thrown by the helpers below and turned into CommandLine::error; never leaves this file.
struct BadArgument : std::runtime_error {
  using std::runtime_error::runtime_error;
};

template <typename Integer>
Integer parse_integer(std::string_view text, std::string_view what) {
  Integer value{};
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size()) {
    throw BadArgument(std::string(what) + ": '" + std::string(text) + "' is not a valid number");
  }
  return value;
}

double parse_double(std::string_view text, std::string_view what, double min, double max) {
  double value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value)) {
    throw BadArgument(std::string(what) + ": '" + std::string(text) + "' is not a number");
  }
  if (value < min || value > max) {
    throw BadArgument(std::string(what) + ": " + std::string(text) + " is outside [" +
                      std::to_string(min) + ", " + std::to_string(max) + "]");
  }
  return value;
}

// Durations are limited to a day: plenty for a test, and far from overflowing nanoseconds.
constexpr double kMaxSeconds = 86400.0;

nanoseconds parse_seconds(std::string_view text, std::string_view what) {
  return nanoseconds(std::llround(parse_double(text, what, 0.0, kMaxSeconds) * 1e9));
}

nanoseconds parse_milliseconds(std::string_view text, std::string_view what) {
  return nanoseconds(std::llround(parse_double(text, what, 0.0, kMaxSeconds * 1e3) * 1e6));
}

// "X:Y" into its two halves (both required).
std::pair<std::string_view, std::string_view> split_pair(std::string_view text, char separator,
                                                         std::string_view what) {
  const std::size_t at = text.find(separator);
  if (at == std::string_view::npos || at == 0 || at + 1 == text.size()) {
    throw BadArgument(std::string(what) + ": expected X" + separator + "Y, got '" +
                      std::string(text) + "'");
  }
  return {text.substr(0, at), text.substr(at + 1)};
}

}  // namespace

std::optional<EndpointSpec> parse_endpoint(std::string_view text, std::string& error) {
  EndpointSpec spec;
  const auto starts_with = [&](std::string_view prefix) {
    if (text.substr(0, prefix.size()) != prefix) return false;
    text.remove_prefix(prefix.size());
    return true;
  };
  if (starts_with("pty:")) {
    if (text.empty()) {
      error = "pty: needs a path";
      return std::nullopt;
    }
    spec.kind = EndpointSpec::Kind::pty;
    spec.path = std::string(text);
    return spec;
  }
  if (starts_with("tcp-listen:")) {
    spec.kind = EndpointSpec::Kind::tcp_listen;
  } else if (starts_with("tcp-connect:")) {
    spec.kind = EndpointSpec::Kind::tcp_connect;
  } else {
    error = "endpoint '" + std::string(text) + "' is not tcp-listen:HOST:PORT, " +
            "tcp-connect:HOST:PORT or pty:PATH";
    return std::nullopt;
  }
  const std::size_t colon = text.rfind(':');
  std::string_view host = colon == std::string_view::npos ? "" : text.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  const std::string_view port = colon == std::string_view::npos ? "" : text.substr(colon + 1);
  unsigned value = 0;
  const auto [end, ec] = std::from_chars(port.data(), port.data() + port.size(), value);
  const bool port_ok = !port.empty() && ec == std::errc() && end == port.data() + port.size() &&
                       value <= 65535 && (value > 0 || spec.kind == EndpointSpec::Kind::tcp_listen);
  if (host.empty() || !port_ok) {
    error =
        "endpoint '" + std::string(text) + "' needs HOST:PORT" +
        (spec.kind == EndpointSpec::Kind::tcp_connect ? " (port 1..65535)" : " (port 0..65535)");
    return std::nullopt;
  }
  spec.host = std::string(host);
  spec.port = static_cast<std::uint16_t>(value);
  return spec;
}

std::string to_string(const EndpointSpec& spec) {
  switch (spec.kind) {
    case EndpointSpec::Kind::pty:
      return "pty:" + spec.path;
    case EndpointSpec::Kind::tcp_listen:
    case EndpointSpec::Kind::tcp_connect: {
      const std::string host =
          spec.host.find(':') == std::string::npos ? spec.host : "[" + spec.host + "]";
      return std::string(spec.kind == EndpointSpec::Kind::tcp_listen ? "tcp-listen:"
                                                                     : "tcp-connect:") +
             host + ":" + std::to_string(spec.port);
    }
  }
  return {};
}

ImpairmentOptions EmulatorOptions::a_to_b() const {
  ImpairmentOptions options = line;
  options.seed = derive_seed(seed, 0xAB);
  return options;
}

ImpairmentOptions EmulatorOptions::b_to_a() const {
  ImpairmentOptions options = line;
  options.seed = derive_seed(seed, 0xBA);
  return options;
}

CommandLine parse_command_line(const std::vector<std::string>& args) {
  CommandLine result;
  EmulatorOptions options;
  std::optional<EndpointSpec> a;
  std::optional<EndpointSpec> b;
  std::optional<unsigned> cut_count;
  std::optional<std::pair<nanoseconds, nanoseconds>> cut_length;
  std::optional<std::pair<nanoseconds, nanoseconds>> cut_window;
  nanoseconds cut_gap{0};
  std::vector<Cut> explicit_cuts;
  try {
    // CLI11 does the grammar (any order, --flag=value, unknown options, missing values); the
    // values are checked below, in one place, with messages naming the option.
    CLI::App app{"canbridge-link-emulator", "canbridge-link-emulator"};
    app.set_help_flag("-h,--help");
    std::map<std::string, std::string> values;
    std::vector<std::string> cut_at;
    for (const char* flag :
         {"--a", "--b", "--baud", "--bits-per-byte", "--latency-ms", "--jitter-ms", "--ber",
          "--loss", "--buffer-bytes", "--seed", "--cuts", "--cut-ms", "--cut-window-s",
          "--cut-gap-ms", "--cut-mode", "--stats-seconds"}) {
      app.add_option(flag, values[flag]);
    }
    app.add_option("--cut-at", cut_at)
        ->expected(1)
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
    auto* version = app.add_flag("--version");
    logging::LogArguments log;
    // The help is kUsage's, so the notes of the options are not printed.
    logging::add_log_options(app, log, "");
    try {
      app.parse(std::vector<std::string>(args.rbegin(), args.rend()));
    } catch (const CLI::CallForHelp&) {
      result.help = true;
      return result;
    } catch (const CLI::ParseError& e) {
      throw BadArgument(logging::usage_message(app, e));
    }
    if (version->count() > 0) {
      result.version = true;
      return result;
    }
    result.log_level = log.log_level();
    result.log_format = log.log_format();
    std::vector<std::pair<std::string, std::string>> given;
    for (const auto& [flag, value] : values) {
      if (app.get_option(flag)->count() > 0) given.emplace_back(flag, value);
    }
    for (const std::string& value : cut_at) given.emplace_back("--cut-at", value);
    for (const auto& [flag, text] : given) {
      const std::string_view value = text;
      if (flag == "--a" || flag == "--b") {
        std::string error;
        auto spec = parse_endpoint(value, error);
        if (!spec) throw BadArgument(flag + ": " + error);
        (flag == "--a" ? a : b) = std::move(spec);
      } else if (flag == "--baud") {
        options.line.bandwidth_bps = parse_integer<std::uint64_t>(value, flag);
        if (options.line.bandwidth_bps > 1'000'000'000'000ull) {
          throw BadArgument("--baud: at most 1e12 bits/s");
        }
      } else if (flag == "--bits-per-byte") {
        options.line.bits_per_byte = parse_integer<unsigned>(value, flag);
        if (options.line.bits_per_byte < 1 || options.line.bits_per_byte > 64) {
          throw BadArgument("--bits-per-byte: 1..64");
        }
      } else if (flag == "--latency-ms") {
        options.line.latency = parse_milliseconds(value, flag);
      } else if (flag == "--jitter-ms") {
        options.line.jitter = parse_milliseconds(value, flag);
      } else if (flag == "--ber") {
        options.line.bit_error_rate = parse_double(value, flag, 0.0, 1.0);
      } else if (flag == "--loss") {
        options.line.byte_loss_rate = parse_double(value, flag, 0.0, 1.0);
      } else if (flag == "--buffer-bytes") {
        options.line.buffer_limit = parse_integer<std::size_t>(value, flag);
        if (options.line.buffer_limit == 0) throw BadArgument("--buffer-bytes: at least 1");
      } else if (flag == "--seed") {
        options.seed = parse_integer<std::uint64_t>(value, flag);
      } else if (flag == "--cuts") {
        cut_count = parse_integer<unsigned>(value, flag);
        if (*cut_count > 100000) throw BadArgument("--cuts: at most 100000");
      } else if (flag == "--cut-ms") {
        if (value.find(':') == std::string_view::npos) {
          const nanoseconds length = parse_milliseconds(value, flag);
          cut_length = {length, length};
        } else {
          const auto [low, high] = split_pair(value, ':', flag);
          cut_length = {parse_milliseconds(low, flag), parse_milliseconds(high, flag)};
        }
      } else if (flag == "--cut-window-s") {
        const auto [low, high] = split_pair(value, ':', flag);
        cut_window = {parse_seconds(low, flag), parse_seconds(high, flag)};
      } else if (flag == "--cut-gap-ms") {
        cut_gap = parse_milliseconds(value, flag);
      } else if (flag == "--cut-at") {
        const auto [start, length] = split_pair(value, '+', flag);
        explicit_cuts.push_back(Cut{parse_seconds(start, flag), parse_seconds(length, flag)});
      } else if (flag == "--cut-mode") {
        if (value == "close") {
          options.cut_mode = EmulatorOptions::CutMode::close;
        } else if (value == "silent") {
          options.cut_mode = EmulatorOptions::CutMode::silent;
        } else {
          throw BadArgument("--cut-mode: close or silent, not '" + std::string(value) + "'");
        }
      } else if (flag == "--stats-seconds") {
        options.stats_interval = std::chrono::seconds(parse_integer<unsigned>(value, flag));
      }
    }
    if (!a || !b) throw BadArgument("both --a SPEC and --b SPEC are required");
    if (a->kind == EndpointSpec::Kind::pty && b->kind == EndpointSpec::Kind::pty &&
        a->path == b->path) {
      throw BadArgument("--a and --b name the same pty path");
    }
    options.a = *a;
    options.b = *b;
    options.line.seed = options.seed;
    if (cut_count && !explicit_cuts.empty()) {
      throw BadArgument("--cuts and --cut-at exclude each other");
    }
    if (cut_count && *cut_count > 0) {
      if (!cut_length || !cut_window) {
        throw BadArgument("--cuts needs --cut-ms and --cut-window-s");
      }
      RandomCuts random;
      random.seed = derive_seed(options.seed, 0xC0);
      random.count = *cut_count;
      random.min_length = cut_length->first;
      random.max_length = cut_length->second;
      random.window_start = cut_window->first;
      random.window_end = cut_window->second;
      random.min_gap = cut_gap;
      options.cuts = CutSchedule::random(random);
    } else if (!cut_count && (cut_length || cut_window)) {
      throw BadArgument("--cut-ms and --cut-window-s need --cuts N");
    } else if (!explicit_cuts.empty()) {
      options.cuts = CutSchedule::from_list(std::move(explicit_cuts));
    }
  } catch (const std::exception& e) {  // BadArgument, and std::invalid_argument from the cores
    result.error = e.what();
    return result;
  }
  result.options = std::move(options);
  return result;
}

std::string format_ready_line(std::string_view a, std::string_view b) {
  return "link-emulator: ready a=" + std::string(a) + " b=" + std::string(b);
}

std::optional<ReadyLine> find_ready_line(std::string_view output) {
  constexpr std::string_view kPrefix = "link-emulator: ready a=";
  const std::size_t at = output.find(kPrefix);
  if (at == std::string_view::npos) return std::nullopt;
  const std::size_t line_end = output.find('\n', at);
  if (line_end == std::string_view::npos) return std::nullopt;  // not complete yet
  const std::string_view line = output.substr(at + kPrefix.size(), line_end - at - kPrefix.size());
  const std::size_t b_at = line.find(" b=");
  if (b_at == std::string_view::npos) return std::nullopt;
  return ReadyLine{std::string(line.substr(0, b_at)), std::string(line.substr(b_at + 3))};
}

std::optional<std::uint16_t> endpoint_port(std::string_view resolved) {
  if (resolved.substr(0, 4) != "tcp-") return std::nullopt;
  const std::size_t colon = resolved.rfind(':');
  if (colon == std::string_view::npos) return std::nullopt;
  unsigned port = 0;
  const std::string_view digits = resolved.substr(colon + 1);
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), port);
  if (ec != std::errc() || end != digits.data() + digits.size() || port > 65535) {
    return std::nullopt;
  }
  return static_cast<std::uint16_t>(port);
}

std::optional<std::string> endpoint_pty_device(std::string_view resolved) {
  if (resolved.substr(0, 4) != "pty:") return std::nullopt;
  const std::size_t arrow = resolved.rfind("->");
  if (arrow == std::string_view::npos) return std::nullopt;
  return std::string(resolved.substr(arrow + 2));
}

std::string format_stats(std::string_view label, const ImpairmentCounters& a_to_b,
                         const ImpairmentCounters& b_to_a) {
  const auto direction = [](std::string_view name, const ImpairmentCounters& c) {
    return std::string(name) + " in=" + std::to_string(c.bytes_in) +
           " out=" + std::to_string(c.bytes_out) + " flipped=" + std::to_string(c.bits_flipped) +
           " lost=" + std::to_string(c.bytes_lost) +
           " cut_dropped=" + std::to_string(c.bytes_dropped_in_cut) +
           " disconnect_dropped=" + std::to_string(c.bytes_dropped_on_disconnect);
  };
  return "link-emulator: " + std::string(label) + " " + direction("a->b", a_to_b) + " " +
         direction("b->a", b_to_a);
}

}  // namespace canbridge::emulator
