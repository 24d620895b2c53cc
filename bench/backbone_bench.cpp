// canbridge-backbone-bench: how many CAN frames per second the backbone session carries, and how
// many wire bytes each costs, over TCP loopback and over an emulated 115200 bit/s line (TCP and a
// pty pair, clean and at a bit error rate of 1e-4), and what the serial line's authentication
// (sealed envelopes) costs against the plain line at 115200 and 1 Mbit/s. One process, one
// io_context(1): a "gateway" end whose producer is a bridge::FrameOutbox kept topped up with
// reliable frames, and a "surface" end that decodes every FrameBatch and checks each frame is
// intact and in order per COB-ID. A measurement, never a test: see bench/README.md.
#include <fcntl.h>
#include <poll.h>
#include <spawn.h>
#include <spdlog/spdlog.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "backbone/serial_client.hpp"
#include "backbone/session.hpp"
#include "backbone/tcp_client.hpp"
#include "backbone/tcp_server.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/frame_outbox.hpp"
#include "canbridge.pb.h"
#include "tools/link_emulator/command_line.hpp"

extern char** environ;

namespace canbridge::bench {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using v1::Hello;

constexpr std::uint32_t kModule = 1;
// EMCY and SDO identifiers: reliable class (never conflated), so every frame offered must arrive.
// Several of them, so that the outbox's arbitration ordering and per-COB-ID order both matter.
constexpr std::array<std::uint32_t, 8> kCobIds = {0x081, 0x082, 0x083, 0x084,
                                                  0x581, 0x582, 0x601, 0x602};
constexpr std::size_t kFrameBytes = 8;
// More than any single write takes (16 KiB / 10 bytes per frame) and more than the slow line's
// resend window: the producer never runs dry, yet the outbox (65,536 reliable) never refuses.
constexpr std::size_t kOutboxTopUp = 8192;

constexpr double kLineBaud = 115200;
constexpr double kLineBitsPerByte = 10;  // 8N1: start, 8 data, stop
constexpr double kLineBytesPerSecond = kLineBaud / kLineBitsPerByte;
constexpr double kCeilingFramesPerSecond = kLineBytesPerSecond / kFrameBytes;

// ---------------------------------------------------------------------------------------------
// The workload: frame k goes to COB-ID kCobIds[k % 8] and carries that COB-ID's sequence number
// (k / 8) in bytes 0-3 and a check word derived from id and sequence in bytes 4-7, so a frame
// delivered twice, out of order, under the wrong id or with a flipped bit shows.

std::uint32_t check_word(std::uint32_t id, std::uint32_t seq) {
  std::uint32_t x = seq * 0x9E3779B1u ^ id * 0x85EBCA77u;
  x ^= x >> 15;
  x *= 0x2C1B3C6Du;
  x ^= x >> 12;
  return x;
}

void put_u32(std::uint8_t* out, std::uint32_t value) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<std::uint8_t>(value >> (8 * i));
}

std::uint32_t get_u32(const std::uint8_t* in) {
  std::uint32_t value = 0;
  for (int i = 0; i < 4; ++i) value |= std::uint32_t{in[i]} << (8 * i);
  return value;
}

can::Frame workload_frame(std::uint64_t index) {
  can::Frame frame;
  frame.id = kCobIds[index % kCobIds.size()];
  frame.len = kFrameBytes;
  const auto seq = static_cast<std::uint32_t>(index / kCobIds.size());
  put_u32(frame.data.data(), seq);
  put_u32(frame.data.data() + 4, check_word(frame.id, seq));
  return frame;
}

// Frames of the workload's first `total` that go to kCobIds[slot].
std::uint64_t frames_for_slot(std::uint64_t total, std::size_t slot) {
  return total / kCobIds.size() + (slot < total % kCobIds.size() ? 1 : 0);
}

std::uint64_t sum_tx_bytes(const std::vector<std::shared_ptr<backbone::SessionLink>>& links) {
  std::uint64_t bytes = 0;
  for (const auto& link : links) bytes += link->message_link()->counters().tx_bytes;
  return bytes;
}

std::uint64_t sum_crc_errors(const std::vector<std::shared_ptr<backbone::SessionLink>>& links) {
  std::uint64_t errors = 0;
  for (const auto& link : links) errors += link->message_link()->counters().deframer.crc_errors;
  return errors;
}

backbone::SessionLink::Identity identity_of(std::string name, Hello::Role role,
                                            std::vector<std::uint32_t> modules) {
  backbone::SessionLink::Identity identity;
  identity.role = role;
  identity.expected_peer = role == Hello::ROLE_GATEWAY ? Hello::ROLE_SURFACE : Hello::ROLE_GATEWAY;
  identity.name = std::move(name);
  identity.module_ids = std::move(modules);
  identity.session_id = backbone::random_session_id();
  return identity;
}

// ---------------------------------------------------------------------------------------------
// The sending end: a FrameOutbox that is refilled from the workload every time the session asks
// it for payloads, as a gateway's outbox is fed by its module bus.
class GatewayEnd {
 public:
  GatewayEnd(const backbone::SessionOptions& options, bridge::FrameOutbox::Options outbox,
             std::uint64_t total)
      : options_(options),
        total_(total),
        outbox_(outbox),
        identity_(identity_of("bench-gateway", Hello::ROLE_GATEWAY, {kModule})),
        stream_(options_, backbone::PeerStream::Handlers{
                              [this](backbone::PayloadSink& sink) { produce(sink); },
                              [](std::span<const std::uint8_t>, bool) {},
                              [this](const Hello& peer) { on_up(peer); }, nullptr}) {}

  void attach(std::shared_ptr<backbone::MessageLink> link) {
    auto session =
        backbone::SessionLink::create(std::move(link), identity_, options_, &stream_, {}, counters);
    session->start();
    links.push_back(std::move(session));
  }

  std::optional<Clock::time_point> first_up;  // the clock of a run starts here
  backbone::SessionCounters counters;
  std::vector<std::shared_ptr<backbone::SessionLink>> links;
  const bridge::FrameOutbox& outbox() const { return outbox_; }

 private:
  void on_up(const Hello& peer) {
    // As the gateway does: head runs only to a peer that decodes them.
    outbox_.set_head_runs(peer.protocol_minor() >= bridge::kHeadRunsMinor);
    if (!first_up) first_up = Clock::now();
  }

  void produce(backbone::PayloadSink& sink) {
    const auto now = sink.now();  // one clock reading per top-up, as the roles read per batch
    while (next_ < total_ && outbox_.size() < kOutboxTopUp) {
      if (!outbox_.push(kModule, workload_frame(next_), {}, now)) break;
      ++next_;
    }
    outbox_.produce(sink);
  }

  backbone::SessionOptions options_;
  std::uint64_t total_;
  std::uint64_t next_ = 0;
  bridge::FrameOutbox outbox_;
  backbone::SessionLink::Identity identity_;
  backbone::PeerStream stream_;
};

// The receiving end: decodes every payload down to frames and checks each against the workload.
class SurfaceEnd {
 public:
  SurfaceEnd(const backbone::SessionOptions& options, std::uint64_t total,
             std::function<void()> on_complete)
      : options_(options),
        total_(total),
        on_complete_(std::move(on_complete)),
        identity_(identity_of("bench-surface", Hello::ROLE_SURFACE, {})),
        stream_(options_, backbone::PeerStream::Handlers{
                              nullptr,
                              [this](std::span<const std::uint8_t> payload, bool reliable) {
                                receive(payload, reliable);
                              },
                              nullptr, nullptr}) {
    for (std::size_t slot = 0; slot < kCobIds.size(); ++slot) slot_of_id_[kCobIds[slot]] = slot;
  }

  void attach(std::shared_ptr<backbone::MessageLink> link) {
    auto session = backbone::SessionLink::create(
        std::move(link), identity_, options_, nullptr,
        [this](const Hello&, backbone::SessionLink&) {
          return backbone::BindResult{&stream_, {}, {}};
        },
        counters);
    session->start();
    links.push_back(std::move(session));
  }

  // Every COB-ID got exactly its share of the workload, and nothing failed a check.
  bool intact() const {
    if (bad_payloads + bad_frames + out_of_order + unreliable_payloads != 0) return false;
    for (std::size_t slot = 0; slot < kCobIds.size(); ++slot) {
      if (next_seq_[slot] != frames_for_slot(total_, slot)) return false;
    }
    return true;
  }

  const backbone::ReliableReceiver::Counters& receiver_counters() const {
    return stream_.receiver().counters();
  }

  std::uint64_t delivered = 0;
  std::optional<Clock::time_point> completed_at;
  std::uint64_t bad_payloads = 0;  // not a Payload, or a FrameBatch that does not decode
  std::uint64_t bad_frames = 0;    // wrong module, id, length, flags or check word
  std::uint64_t out_of_order = 0;  // sequence number of its COB-ID not the next one
  std::uint64_t unreliable_payloads = 0;
  backbone::SessionCounters counters;
  std::vector<std::shared_ptr<backbone::SessionLink>> links;

 private:
  static constexpr std::size_t kNoSlot = kCobIds.size();

  void receive(std::span<const std::uint8_t> payload, bool reliable) {
    if (!reliable) ++unreliable_payloads;
    if (!payload_.ParseFromArray(payload.data(), static_cast<int>(payload.size())) ||
        !payload_.has_frames()) {
      ++bad_payloads;
      return;
    }
    frames_.clear();
    if (bridge::decode_frame_batch(payload_.frames(), frames_) != bridge::BatchError::none) {
      ++bad_payloads;
      return;
    }
    const bool right_module = payload_.frames().module_id() == kModule;
    for (const can::Frame& frame : frames_) check(frame, right_module);
    delivered += frames_.size();
    if (delivered >= total_ && !completed_at) {
      completed_at = Clock::now();
      if (on_complete_) on_complete_();
    }
  }

  void check(const can::Frame& frame, bool right_module) {
    const std::size_t slot = frame.id <= can::kMaxStandardId ? slot_of_id_[frame.id] : kNoSlot;
    if (!right_module || slot == kNoSlot || frame.flags != 0 || frame.len != kFrameBytes) {
      ++bad_frames;
      return;
    }
    const std::uint32_t seq = get_u32(frame.data.data());
    if (get_u32(frame.data.data() + 4) != check_word(frame.id, seq)) {
      ++bad_frames;
      return;
    }
    if (seq != next_seq_[slot]) ++out_of_order;
    next_seq_[slot] = seq + 1;  // resynchronise, so one fault is counted once
  }

  backbone::SessionOptions options_;
  std::uint64_t total_;
  std::function<void()> on_complete_;
  backbone::SessionLink::Identity identity_;
  backbone::PeerStream stream_;
  v1::Payload payload_;
  std::vector<can::Frame> frames_;
  std::array<std::size_t, can::kMaxStandardId + 1> slot_of_id_ = filled_no_slot();
  std::array<std::uint64_t, kCobIds.size()> next_seq_{};

  static std::array<std::size_t, can::kMaxStandardId + 1> filled_no_slot() {
    std::array<std::size_t, can::kMaxStandardId + 1> a;
    a.fill(kNoSlot);
    return a;
  }
};

// ---------------------------------------------------------------------------------------------
// canbridge-link-emulator as a child: stdout (ready and stats lines) through a pipe, stderr (its
// per-connection diagnostics) to a log file, SIGTERM and reaped on stop or destruction.
class EmulatorProcess {
 public:
  EmulatorProcess(const std::vector<std::string>& argv, const std::filesystem::path& log) {
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("pipe2 failed");
    out_fd_ = fds[0];
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_adddup2(&actions, fds[1], 1);
    posix_spawn_file_actions_addopen(&actions, 2, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    std::vector<char*> args;
    for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const int error = ::posix_spawn(&pid_, args[0], &actions, nullptr, args.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(fds[1]);
    if (error != 0) {
      pid_ = -1;
      ::close(out_fd_);
      out_fd_ = -1;
      throw std::runtime_error("cannot start " + argv[0] + ": " + std::strerror(error));
    }
  }
  ~EmulatorProcess() {
    if (pid_ > 0) stop();
    if (out_fd_ >= 0) ::close(out_fd_);
  }
  EmulatorProcess(const EmulatorProcess&) = delete;
  EmulatorProcess& operator=(const EmulatorProcess&) = delete;

  // Blocks until the ready line arrived (before the io_context runs, so nothing else waits).
  std::optional<emulator::ReadyLine> wait_ready(std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    while (Clock::now() < deadline) {
      if (auto ready = emulator::find_ready_line(output_)) return ready;
      if (!read_some(deadline)) break;
    }
    return emulator::find_ready_line(output_);
  }

  // SIGTERM, then what it still prints (its final stats line), then reaps it.
  void stop() {
    ::kill(pid_, SIGTERM);
    const auto deadline = Clock::now() + 5s;
    while (read_some(deadline)) {
    }
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, &status, 0);
    }
    pid_ = -1;
  }

 private:
  // One read of stdout; false at EOF or when the deadline passed.
  bool read_some(Clock::time_point deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left <= 0ms) return false;
    pollfd p{out_fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return false;
    char buffer[4096];
    const ssize_t n = ::read(out_fd_, buffer, sizeof buffer);
    if (n <= 0) return false;
    output_.append(buffer, static_cast<std::size_t>(n));
    return true;
  }

  pid_t pid_ = -1;
  int out_fd_ = -1;
  std::string output_;
};

// ---------------------------------------------------------------------------------------------
enum class Transport { tcp_loopback, tcp_emulated, serial_emulated };

struct Scenario {
  std::string name;
  Transport transport;
  std::string ber;  // emulator --ber, empty: a clean line
  std::uint64_t frames;
  backbone::SessionOptions session;
  bridge::FrameOutbox::Options outbox;
  bool slow_line;  // the line's ceiling applies
  double baud = kLineBaud;
  // The session authenticates (challenge-response, then every envelope sealed: docs/security.md)
  bool mac = false;
  double ceiling_frames_per_second() const {
    return baud / kLineBitsPerByte / static_cast<double>(kFrameBytes);
  }
};

// Session options with the serial line's authentication (PSK, 16-byte tags) for one end.
backbone::SessionOptions with_mac(backbone::SessionOptions o, backbone::AuthRole role) {
  o.authenticator = [role](const std::string&) {
    backbone::PeerAuthenticatorOptions a;
    a.role = role;
    a.own_identity = role == backbone::AuthRole::gateway ? "bench-gateway" : "bench-surface";
    a.peer_identity = role == backbone::AuthRole::gateway ? "bench-surface" : "bench-gateway";
    std::array<std::uint8_t, backbone::kPreSharedKeySize> key{};
    key.fill(0x42);
    a.keys.emplace_back(key);
    return std::make_unique<backbone::PeerAuthenticator>(std::move(a));
  };
  return o;
}

struct RunResult {
  bool completed = false;
  bool intact = false;
  double seconds = 0;
  std::uint64_t delivered = 0;
  std::uint64_t data_bytes = 0;  // gateway -> surface, all the gateway's links
  std::uint64_t ack_bytes = 0;   // surface -> gateway
  std::uint64_t batches = 0;
  std::uint64_t resent = 0;           // reliable payloads retransmitted by the gateway
  std::uint64_t resend_requests = 0;  // gaps the surface reported
  std::uint64_t gap_dropped = 0;      // payloads the surface dropped because one before was lost
  std::uint64_t duplicates = 0;       // payloads the surface had already delivered
  std::uint64_t crc_errors = 0;       // frames the surface's deframer dropped
  std::uint64_t links = 0;            // gateway links that came up (1: never reconnected)
  // Links either end closed on a protocol error or as dead (a lost hello on a noisy line, ...).
  std::uint64_t link_failures = 0;
  double frames_per_second() const {
    return seconds > 0 ? static_cast<double>(delivered) / seconds : 0;
  }
  double bytes_per_frame() const { return per_frame(data_bytes); }
  double ack_bytes_per_frame() const { return per_frame(ack_bytes); }
  double per_frame(std::uint64_t bytes) const {
    return delivered ? static_cast<double>(bytes) / static_cast<double>(delivered) : 0;
  }
};

struct BenchConfig {
  int runs = 5;
  std::optional<std::uint64_t> loopback_frames;
  std::optional<std::uint64_t> line_frames;
  std::optional<std::uint64_t> ber_frames;
  std::vector<std::string> only;
  std::string emulator;
  std::chrono::seconds run_timeout{30};
  std::optional<std::size_t> line_resend_bytes;
  std::optional<std::size_t> line_batch_bytes;
};

std::vector<std::string> emulator_argv(const BenchConfig& config, const Scenario& scenario,
                                       const std::string& a, const std::string& b, int run) {
  std::vector<std::string> argv = {config.emulator,
                                   "--a",
                                   a,
                                   "--b",
                                   b,
                                   "--baud",
                                   std::to_string(static_cast<unsigned>(scenario.baud)),
                                   "--seed",
                                   std::to_string(20261200 + run)};
  if (!scenario.ber.empty()) {
    argv.push_back("--ber");
    argv.push_back(scenario.ber);
  }
  return argv;
}

RunResult run_once(const BenchConfig& config, const Scenario& scenario, int run,
                   const std::filesystem::path& work) {
  asio::io_context io{1};
  GatewayEnd gateway(
      scenario.mac ? with_mac(scenario.session, backbone::AuthRole::gateway) : scenario.session,
      scenario.outbox, scenario.frames);
  SurfaceEnd surface(
      scenario.mac ? with_mac(scenario.session, backbone::AuthRole::surface) : scenario.session,
      scenario.frames, [&io] { io.stop(); });

  backbone::ClientOptions client_options;
  client_options.backoff_min = 20ms;
  client_options.backoff_max = 200ms;
  std::shared_ptr<backbone::TcpServer> server;
  std::shared_ptr<backbone::TcpClient> client;
  std::shared_ptr<backbone::SerialClient> gateway_line;
  std::shared_ptr<backbone::SerialClient> surface_line;
  std::unique_ptr<EmulatorProcess> emulator;
  const auto emulator_log = work / (scenario.name + "-emulator.log");

  if (scenario.transport != Transport::serial_emulated) {
    server = backbone::TcpServer::create(io.get_executor());
    if (server->start("127.0.0.1", 0, [&](auto link) { surface.attach(link); })) {
      throw std::runtime_error("cannot listen on 127.0.0.1");
    }
    std::uint16_t port = server->port();
    if (scenario.transport == Transport::tcp_emulated) {
      emulator = std::make_unique<EmulatorProcess>(
          emulator_argv(config, scenario, "tcp-listen:127.0.0.1:0",
                        "tcp-connect:127.0.0.1:" + std::to_string(port), run),
          emulator_log);
      const auto ready = emulator->wait_ready(5s);
      const auto emulated_port = ready ? emulator::endpoint_port(ready->a) : std::nullopt;
      if (!emulated_port) {
        throw std::runtime_error("link emulator not ready, see " + emulator_log.string());
      }
      port = *emulated_port;
    }
    client = backbone::TcpClient::create(io.get_executor(), "127.0.0.1", port, client_options);
    client->start([&](auto link) { gateway.attach(link); });
  } else {
    const auto gw_pty = work / "gw";
    const auto surface_pty = work / "surface";
    emulator =
        std::make_unique<EmulatorProcess>(emulator_argv(config, scenario, "pty:" + gw_pty.string(),
                                                        "pty:" + surface_pty.string(), run),
                                          emulator_log);
    if (!emulator->wait_ready(5s)) {
      throw std::runtime_error("link emulator not ready, see " + emulator_log.string());
    }
    auto line = [&](const std::filesystem::path& device) {
      backbone::SerialOptions o;
      o.device = device.string();
      o.baud =
          static_cast<unsigned>(scenario.baud);  // a pty ignores it; the emulator sets the pace
      o.backoff_min = 20ms;
      o.backoff_max = 200ms;
      return backbone::SerialClient::create(io.get_executor(), o);
    };
    gateway_line = line(gw_pty);
    surface_line = line(surface_pty);
    gateway_line->start([&](auto link) { gateway.attach(link); });
    surface_line->start([&](auto link) { surface.attach(link); });
  }

  asio::steady_timer deadline(io);
  deadline.expires_after(config.run_timeout);
  deadline.async_wait([&io](boost::system::error_code ec) {
    if (!ec) io.stop();
  });
  io.run();

  RunResult r;
  r.completed = surface.completed_at.has_value() && gateway.first_up.has_value();
  r.delivered = surface.delivered;
  const Clock::time_point end = surface.completed_at.value_or(Clock::now());
  if (gateway.first_up) r.seconds = std::chrono::duration<double>(end - *gateway.first_up).count();
  r.data_bytes = sum_tx_bytes(gateway.links);
  r.ack_bytes = sum_tx_bytes(surface.links);
  r.batches = gateway.outbox().counters().batches_sent;
  r.resent = gateway.counters.reliable_resent;
  r.resend_requests = surface.counters.resend_requests;
  r.gap_dropped = surface.receiver_counters().gaps;
  r.duplicates = surface.counters.reliable_duplicates;
  r.crc_errors = sum_crc_errors(surface.links);
  r.links = gateway.counters.links;
  r.link_failures = gateway.counters.protocol_errors + gateway.counters.dead_links +
                    surface.counters.protocol_errors + surface.counters.dead_links;
  r.intact = r.completed && surface.intact();

  deadline.cancel();
  if (client) client->stop();
  if (server) server->stop();
  if (gateway_line) gateway_line->stop();
  if (surface_line) surface_line->stop();
  io.restart();
  io.run_for(50ms);
  if (emulator) emulator->stop();
  if (!r.intact) {
    std::fprintf(stderr,
                 "  %s run %d: %s: delivered %llu/%llu, bad payloads %llu, bad frames %llu, out "
                 "of order %llu, unreliable %llu (emulator log: %s)\n",
                 scenario.name.c_str(), run, r.completed ? "NOT INTACT" : "TIMED OUT",
                 static_cast<unsigned long long>(surface.delivered),
                 static_cast<unsigned long long>(scenario.frames),
                 static_cast<unsigned long long>(surface.bad_payloads),
                 static_cast<unsigned long long>(surface.bad_frames),
                 static_cast<unsigned long long>(surface.out_of_order),
                 static_cast<unsigned long long>(surface.unreliable_payloads),
                 emulator_log.c_str());
  }
  return r;
}

// ---------------------------------------------------------------------------------------------
struct Spread {
  double median = 0;
  double min = 0;
  double max = 0;
};

// Median of an odd count is the middle value; of an even count, the mean of the two middle ones.
Spread spread(std::vector<double> values) {
  if (values.empty()) return {};
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  const double median = n % 2 ? values[n / 2] : (values[n / 2 - 1] + values[n / 2]) / 2;
  return {median, values.front(), values.back()};
}

template <class Field>
Spread spread_of(const std::vector<RunResult>& runs, Field field) {
  std::vector<double> values;
  for (const RunResult& r : runs) values.push_back(field(r));
  return spread(values);
}

backbone::SessionOptions slow_line_session(const BenchConfig& config) {
  backbone::SessionOptions o;
  // A 512-byte write is 44 ms of line: what is urgent never waits longer behind one.
  o.max_write_bytes = 512;
  // Bandwidth x RTT with room to spare: 11.5 KB/s x (one 512-byte write each way + queueing).
  o.resend_buffer_bytes = config.line_resend_bytes.value_or(8 * 1024);
  o.retransmit_timeout = 1s;
  o.keepalive_interval = 200ms;
  o.dead_after = 1s;
  return o;
}

// 1 Mbit/s: nine times the bandwidth, so nine times the writes and window for the same delay.
backbone::SessionOptions fast_line_session(const BenchConfig& config) {
  backbone::SessionOptions o = slow_line_session(config);
  o.max_write_bytes = 4096;
  o.resend_buffer_bytes = config.line_resend_bytes.value_or(64 * 1024);
  return o;
}

// The batch bound the gateway derives from its session tuning (app/tuning_from_options.hpp,
// make_tuning): never more than a write, nor a quarter of the resend buffer, nor 4 KiB.
std::size_t gateway_batch_bytes(const backbone::SessionOptions& session) {
  return std::max<std::size_t>(
      64, std::min({session.max_write_bytes, session.resend_buffer_bytes / 4, std::size_t{4096}}));
}

std::vector<Scenario> scenarios(const BenchConfig& config) {
  const std::uint64_t line_frames = config.line_frames.value_or(4000);
  // Go-back-N at 1e-4 carries ~100-300 frames/s where the clean line carries ~1,100: a quarter of
  // the frames keeps a run near the clean line's few seconds (and all runs within the budget).
  const std::uint64_t ber_frames = config.ber_frames.value_or(1000);
  const auto slow = slow_line_session(config);
  bridge::FrameOutbox::Options slow_outbox;
  slow_outbox.max_batch_bytes = config.line_batch_bytes.value_or(gateway_batch_bytes(slow));
  const auto fast = fast_line_session(config);
  bridge::FrameOutbox::Options fast_outbox;
  fast_outbox.max_batch_bytes = config.line_batch_bytes.value_or(gateway_batch_bytes(fast));
  const backbone::SessionOptions tcp;
  bridge::FrameOutbox::Options tcp_outbox;
  tcp_outbox.max_batch_bytes = gateway_batch_bytes(tcp);
  std::vector<Scenario> all = {
      {"tcp-loopback", Transport::tcp_loopback, "", config.loopback_frames.value_or(200000), tcp,
       tcp_outbox, false},
      {"tcp-emulated-115200", Transport::tcp_emulated, "", line_frames, slow, slow_outbox, true},
      {"serial-emulated-115200", Transport::serial_emulated, "", line_frames, slow, slow_outbox,
       true},
      {"serial-emulated-115200-ber1e-4", Transport::serial_emulated, "1e-4", ber_frames, slow,
       slow_outbox, true},
      // The serial line's authentication (every envelope sealed: 4-byte counter, 16-byte tag)
      // against the plain line, at 115200 and at 1 Mbit/s.
      {"serial-emulated-115200-mac", Transport::serial_emulated, "", line_frames, slow, slow_outbox,
       true, kLineBaud, true},
      {"serial-emulated-1M", Transport::serial_emulated, "", 10 * line_frames, fast, fast_outbox,
       true, 1e6, false},
      {"serial-emulated-1M-mac", Transport::serial_emulated, "", 10 * line_frames, fast,
       fast_outbox, true, 1e6, true},
  };
  if (config.only.empty()) return all;
  std::vector<Scenario> chosen;
  for (const Scenario& s : all) {
    if (std::find(config.only.begin(), config.only.end(), s.name) != config.only.end()) {
      chosen.push_back(s);
    }
  }
  return chosen;
}

// The emulator next to this binary, or in the build tree's tools/link_emulator/.
std::string find_emulator() {
  std::error_code ec;
  const auto self = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    for (const auto& candidate :
         {self.parent_path() / "canbridge-link-emulator",
          self.parent_path().parent_path() / "tools/link_emulator/canbridge-link-emulator"}) {
      if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
    }
  }
  return CANBRIDGE_LINK_EMULATOR_BIN;
}

constexpr const char* kUsage = R"(usage: canbridge-backbone-bench [options]
  --runs R                 runs per scenario (default 5); medians and min/max are reported
  --frames N               CAN frames per run, every scenario
  --loopback-frames N      frames per run over TCP loopback (default 200000)
  --line-frames N          frames per run over the clean 115200 bit/s line (default 4000, ~4 s)
  --ber-frames N           frames per run over the line at BER 1e-4 (default 1000, ~3-9 s)
  --scenario NAME          only this scenario (repeatable): tcp-loopback, tcp-emulated-115200,
                           serial-emulated-115200, serial-emulated-115200-ber1e-4
  --emulator PATH          canbridge-link-emulator (default: next to this binary or in the
                           build tree)
  --line-resend-bytes B    resend window on the 115200 line (default 8192)
  --line-batch-bytes B     FrameBatch bound on the 115200 line (default as the gateway derives
                           it: min(max write 512, resend window / 4, 4096))
  --timeout-s S            a run that has not delivered everything by then fails (default 30)
  --verbose                the session's info logs (links up and down)
)";

std::uint64_t parse_count(const char* text) {
  char* end = nullptr;
  const unsigned long long value = std::strtoull(text, &end, 10);
  if (end == text || *end != '\0' || value == 0) {
    throw std::invalid_argument(std::string("not a positive number: ") + text);
  }
  return value;
}

BenchConfig parse_arguments(int argc, char** argv) {
  BenchConfig config;
  bool verbose = false;
  for (int i = 1; i < argc; ++i) {
    const std::string_view arg = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) throw std::invalid_argument(std::string(arg) + " needs a value");
      return argv[++i];
    };
    if (arg == "--runs") {
      config.runs = static_cast<int>(parse_count(value()));
    } else if (arg == "--frames") {
      config.loopback_frames = config.line_frames = config.ber_frames = parse_count(value());
    } else if (arg == "--loopback-frames") {
      config.loopback_frames = parse_count(value());
    } else if (arg == "--line-frames") {
      config.line_frames = parse_count(value());
    } else if (arg == "--scenario") {
      config.only.emplace_back(value());
    } else if (arg == "--emulator") {
      config.emulator = value();
    } else if (arg == "--ber-frames") {
      config.ber_frames = parse_count(value());
    } else if (arg == "--line-batch-bytes") {
      config.line_batch_bytes = parse_count(value());
    } else if (arg == "--line-resend-bytes") {
      config.line_resend_bytes = parse_count(value());
    } else if (arg == "--timeout-s") {
      config.run_timeout = std::chrono::seconds(parse_count(value()));
    } else if (arg == "--verbose") {
      verbose = true;
    } else if (arg == "--help" || arg == "-h") {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else {
      throw std::invalid_argument("unknown option " + std::string(arg));
    }
  }
  if (config.emulator.empty()) config.emulator = find_emulator();
  // Link up/down lines at info would interleave with the table; warnings (dead links) stay.
  spdlog::set_level(verbose ? spdlog::level::info : spdlog::level::warn);
  return config;
}

void print_run(const Scenario& scenario, int run, const RunResult& r) {
  std::printf("%-31s %3d %8llu %7.3f %10.0f %9.2f %9.2f", scenario.name.c_str(), run,
              static_cast<unsigned long long>(r.delivered), r.seconds, r.frames_per_second(),
              r.bytes_per_frame(), r.ack_bytes_per_frame());
  if (scenario.slow_line) {
    std::printf(" %6.3f", r.frames_per_second() / scenario.ceiling_frames_per_second());
  } else {
    std::printf(" %6s", "-");
  }
  std::printf(
      " %7llu %6llu %5llu %5llu %5llu %5llu %3llu %4llu %s\n",
      static_cast<unsigned long long>(r.batches), static_cast<unsigned long long>(r.resent),
      static_cast<unsigned long long>(r.resend_requests),
      static_cast<unsigned long long>(r.gap_dropped), static_cast<unsigned long long>(r.duplicates),
      static_cast<unsigned long long>(r.crc_errors), static_cast<unsigned long long>(r.links),
      static_cast<unsigned long long>(r.link_failures), r.intact ? "ok" : "FAIL");
  std::fflush(stdout);
}

struct Summary {
  std::string scenario;
  std::uint64_t frames;
  int runs_ok;
  int runs;
  bool slow_line;
  double ceiling;
  Spread fps, bpf, ack, ratio, resent;
};

int run_bench(const BenchConfig& config) {
  const auto work = std::filesystem::temp_directory_path() /
                    ("canbridge-backbone-bench-" + std::to_string(::getpid()));
  std::filesystem::create_directories(work);
  std::printf(
      "line ceiling at %.0f bit/s, %g bits per byte: %.0f bytes/s = %.0f frames/s of %zu "
      "payload bytes (ratio = payload bytes/s / line bytes/s)\n",
      kLineBaud, kLineBitsPerByte, kLineBytesPerSecond, kCeilingFramesPerSecond, kFrameBytes);
  std::printf("emulator: %s\n", config.emulator.c_str());
  std::fputs(
      "resent: payloads retransmitted, rreq: resend requests, gapdr: dropped after a gap,\n"
      "dup: duplicates received, crc: frames failing the CRC, up: gateway links that came up,\n"
      "fail: links closed as dead or on a protocol error (all counts per run)\n\n",
      stdout);
  std::printf("%-31s %3s %8s %7s %10s %9s %9s %6s %7s %6s %5s %5s %5s %5s %3s %4s %s\n", "scenario",
              "run", "frames", "s", "frames/s", "B/frame", "ackB/fr", "ratio", "batches", "resent",
              "rreq", "gapdr", "dup", "crc", "up", "fail", "check");

  std::vector<Summary> summaries;
  bool all_intact = true;
  for (const Scenario& scenario : scenarios(config)) {
    std::vector<RunResult> ok;
    for (int run = 1; run <= config.runs; ++run) {
      const RunResult r = run_once(config, scenario, run, work);
      print_run(scenario, run, r);
      if (r.intact) {
        ok.push_back(r);
      } else {
        all_intact = false;
      }
    }
    summaries.push_back(
        {scenario.name, scenario.frames, static_cast<int>(ok.size()), config.runs,
         scenario.slow_line, scenario.ceiling_frames_per_second(),
         spread_of(ok, [](const RunResult& r) { return r.frames_per_second(); }),
         spread_of(ok, [](const RunResult& r) { return r.bytes_per_frame(); }),
         spread_of(ok, [](const RunResult& r) { return r.ack_bytes_per_frame(); }),
         spread_of(ok,
                   [&](const RunResult& r) {
                     return r.frames_per_second() / scenario.ceiling_frames_per_second();
                   }),
         spread_of(ok, [](const RunResult& r) { return static_cast<double>(r.resent); })});
  }
  // A failed run's emulator log stays for a look.
  if (all_intact) {
    std::filesystem::remove_all(work);
  } else {
    std::printf("some runs failed: emulator logs kept in %s\n", work.c_str());
  }

  std::printf("\nmedians over the intact runs [min..max]:\n");
  std::printf("%-31s %7s %-26s %-22s %-20s %-22s\n", "scenario", "runs", "frames/s",
              "wire B/frame (data)", "ack B/frame", "ratio to line");
  for (const Summary& s : summaries) {
    char fps[64], bpf[64], ack[64], ratio[64];
    std::snprintf(fps, sizeof fps, "%.0f [%.0f..%.0f]", s.fps.median, s.fps.min, s.fps.max);
    std::snprintf(bpf, sizeof bpf, "%.2f [%.2f..%.2f]", s.bpf.median, s.bpf.min, s.bpf.max);
    std::snprintf(ack, sizeof ack, "%.2f [%.2f..%.2f]", s.ack.median, s.ack.min, s.ack.max);
    if (s.slow_line) {
      std::snprintf(ratio, sizeof ratio, "%.3f [%.3f..%.3f]", s.ratio.median, s.ratio.min,
                    s.ratio.max);
    } else {
      std::snprintf(ratio, sizeof ratio, "-");
    }
    std::printf("%-31s %3d/%-3d %-26s %-22s %-20s %-22s\n", s.scenario.c_str(), s.runs_ok, s.runs,
                fps, bpf, ack, ratio);
  }
  std::printf("\n");
  for (const Summary& s : summaries) {
    std::printf(
        "RESULT scenario=%s frames=%llu runs=%d runs_ok=%d frames_per_s_median=%.0f "
        "frames_per_s_min=%.0f frames_per_s_max=%.0f bytes_per_frame_median=%.3f "
        "bytes_per_frame_min=%.3f bytes_per_frame_max=%.3f ack_bytes_per_frame_median=%.3f "
        "resent_median=%.0f",
        s.scenario.c_str(), static_cast<unsigned long long>(s.frames), s.runs, s.runs_ok,
        s.fps.median, s.fps.min, s.fps.max, s.bpf.median, s.bpf.min, s.bpf.max, s.ack.median,
        s.resent.median);
    if (s.slow_line) {
      std::printf(" ceiling_frames_per_s=%.0f ratio_median=%.4f ratio_min=%.4f ratio_max=%.4f",
                  s.ceiling, s.ratio.median, s.ratio.min, s.ratio.max);
    }
    std::printf("\n");
  }
  return all_intact ? 0 : 1;
}

}  // namespace
}  // namespace canbridge::bench

int main(int argc, char** argv) {
  try {
    return canbridge::bench::run_bench(canbridge::bench::parse_arguments(argc, argv));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "canbridge-backbone-bench: %s\n%s", e.what(), canbridge::bench::kUsage);
    return 2;
  }
}
