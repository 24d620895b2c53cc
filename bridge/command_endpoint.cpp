#include "bridge/command_endpoint.hpp"

#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/generic/stream_protocol.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/local/stream_protocol.hpp>
#include <boost/asio/read_until.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <deque>
#include <fstream>
#include <map>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "bridge/endpoint_server.hpp"
#include "canopen/ascii_command.hpp"
#include "canopen/ascii_response.hpp"
#include "canopen/ascii_value.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/little_endian.hpp"
#include "canopen/sdo_abort.hpp"
#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;
using canopen::AsciiCommand;
using canopen::AsciiError;
using canopen::AsciiVerb;
// A client's socket, Unix or TCP alike: one Session type serves both.
using Socket = asio::generic::stream_protocol::socket;
using Local = asio::local::stream_protocol;
using Tcp = asio::ip::tcp;

namespace {

using coro::kNoError;
// Commands of one client whose answers are not yet written: beyond, the endpoint stops reading
// from it until answers go out, so a pipelining client cannot grow memory without bound.
constexpr std::size_t kMaxPipelined = 64;
// What a TCP client may send before it authenticated: an auth line, nothing big.
constexpr std::size_t kPreAuthLineBytes = 8 * 1024;
// Bytes handed to one socket write.
constexpr std::size_t kWriteBatch = 64 * 1024;
// The block size a session's `set sdo_block 1` asks for (CiA 301's largest).
constexpr std::uint8_t kBlockSize = 127;
// A firmware image larger than this is not an image (a device file, a mistake).
constexpr std::uintmax_t kMaxImageBytes = 64ull * 1024 * 1024;

// Compares in a time that depends on the lengths only, so a wrong token's bytes leak nothing.
bool same_token(std::string_view a, std::string_view b) {
  unsigned diff = a.size() == b.size() ? 0u : 1u;
  const std::size_t n = std::max(a.size(), b.size());
  for (std::size_t i = 0; i < n; ++i) {
    const auto x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0u;
    const auto y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0u;
    diff |= x ^ y;
  }
  return diff == 0;
}

bool allowed_for_monitor(AsciiVerb verb) {
  switch (verb) {
    case AsciiVerb::none:
    case AsciiVerb::read:
    case AsciiVerb::set_network:
    case AsciiVerb::set_node:
    case AsciiVerb::set_sdo_timeout:
    case AsciiVerb::set_sdo_block:
    case AsciiVerb::set_error_detail:
    case AsciiVerb::help:
    case AsciiVerb::auth:
    case AsciiVerb::nodes:
    case AsciiVerb::monitor:
    case AsciiVerb::stats:
      return true;
    case AsciiVerb::write:
    case AsciiVerb::nmt:
    case AsciiVerb::lss:
    case AsciiVerb::flash:
    case AsciiVerb::set_node_id:
      return false;
  }
  return false;
}

NmtCommand to_nmt(canopen::AsciiNmt nmt) {
  switch (nmt) {
    case canopen::AsciiNmt::start:
      return NmtCommand::start;
    case canopen::AsciiNmt::stop:
      return NmtCommand::stop;
    case canopen::AsciiNmt::preoperational:
      return NmtCommand::preoperational;
    case canopen::AsciiNmt::reset_node:
      return NmtCommand::reset_node;
    case canopen::AsciiNmt::reset_communication:
      return NmtCommand::reset_communication;
  }
  return NmtCommand::start;
}

std::string state_text(const NodeRow& row) {
  if (row.lost) return "lost";
  if (row.in_loader) return "loader";
  if (row.nmt_state == static_cast<std::uint8_t>(canopen::NmtState::unknown)) return "unknown";
  const std::string name = canopen::nmt_state_name(row.nmt_state);
  return name == "unknown" ? std::to_string(row.nmt_state) : name;
}

std::string or_dash(const std::string& text) {
  return text.empty() ? "-" : text;
}

// One `node ...` line of the nodes command (docs/remote-access.md), without sequence or CR LF.
std::string node_line(const NodeRow& row) {
  std::string line =
      "node net=" + std::to_string(row.net) + " module=" + std::to_string(row.module_id) +
      " gateway=" + or_dash(row.gateway) + " local=" + std::to_string(row.local_node) +
      " surface=" + (row.surface_node == 0 ? std::string("-") : std::to_string(row.surface_node)) +
      " profile=" + or_dash(row.profile) + " kind=" + or_dash(row.kind) +
      " state=" + state_text(row) +
      " hb_age_ms=" + (row.heartbeat_age ? std::to_string(row.heartbeat_age->count()) : "-") +
      " boot_count=" + std::to_string(row.boot_count) + " emcy=";
  if (row.last_emcy_code) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "%04X/%02X", static_cast<unsigned>(*row.last_emcy_code),
                  static_cast<unsigned>(row.last_emcy_register));
    line += buf;
  } else {
    line += "-";
  }
  return line;
}

std::string frame_line(const MonitorFrame& frame) {
  return "FRAME " + std::to_string(frame.time_us) + " " + std::to_string(frame.module_id) +
         (frame.to_surface_bus ? " > " : " < ") + can::to_string(frame.frame) + "\r\n";
}

// The error response for a request's failure (bridge/remote_access.hpp lists the kinds).
// `with_detail`: canbridge's reason after the reference text
// (CommandEndpointOptions::error_detail).
std::string failure_text(std::optional<std::uint32_t> seq, const RemoteOutcome& outcome,
                         bool with_detail) {
  const std::error_code& error = outcome.error;
  if (error.category() == canopen::sdo_category()) {
    return canopen::ascii_sdo_abort(seq, static_cast<std::uint32_t>(error.value()),
                                    with_detail ? outcome.detail : std::string());
  }
  const std::string detail = !with_detail             ? std::string()
                             : outcome.detail.empty() ? error.message()
                                                      : outcome.detail;
  if (error == std::errc::no_such_device_or_address) {
    return canopen::ascii_error(seq, AsciiError::unsupported_node, detail);
  }
  if (error == std::errc::host_unreachable) {
    return canopen::ascii_error(seq, AsciiError::lost_connection, detail);
  }
  if (error == std::errc::timed_out) return canopen::ascii_error(seq, AsciiError::timeout, detail);
  if (error == make_error_code(RemoteEnd::outcome_unknown)) {
    return canopen::ascii_error(seq, AsciiError::outcome_unknown, detail);
  }
  if (error == std::errc::permission_denied) {
    return canopen::ascii_error(seq, AsciiError::request_not_supported, detail);
  }
  return canopen::ascii_error(seq, AsciiError::internal_state, detail);
}

// The answer of an LSS inquiry: its 32-bit values (little-endian in the data) as CANopenNode
// prints them, the node id as 0x%02X.
std::string lss_answer(const std::string& command, const std::vector<std::uint8_t>& data) {
  char buf[16];
  if (command == "lss_get_node") {
    std::snprintf(buf, sizeof buf, "0x%02X", data.empty() ? 0u : data[0]);
    return buf;
  }
  std::string out;
  for (std::size_t i = 0; i + 4 <= data.size(); i += 4) {
    std::snprintf(buf, sizeof buf, "0x%08X",
                  canopen::load_le32(std::span<const std::uint8_t>(data).subspan(i, 4)));
    if (!out.empty()) out += ' ';
    out += buf;
  }
  return out;
}

class Session;

}  // namespace

struct CommandEndpoint::Core : std::enable_shared_from_this<CommandEndpoint::Core> {
  // The accept loops, the client limit and the per-client coroutine are the shared skeleton's
  // (bridge/endpoint_server.hpp); one limit counts the clients of both listeners.
  using UnixServer = EndpointServer<Local::acceptor, Socket>;
  using TcpServer = EndpointServer<Tcp::acceptor, Socket>;

  Core(asio::any_io_executor ex, CommandEndpointOptions opts, RemoteAccess& r)
      : executor(std::move(ex)),
        options(std::move(opts)),
        remote(r),
        slots(std::make_shared<ClientSlots>(ClientSlots{options.max_clients, 0})) {}

  void start();
  void stop();
  void listen_unix();
  void listen_tcp();
  // One client, from its first byte to its close (its Session's reader and writer).
  static asio::awaitable<void> serve(std::shared_ptr<Core> self, std::shared_ptr<Socket> socket,
                                     bool tcp);
  // A client past max_clients: told why on its fresh socket, then closed by the server.
  template <typename Fresh>
  void refuse(Fresh& socket, const std::string& peer);
  // Which client a TCP token belongs to; nullptr for none. Looks at every client every time.
  const EndpointClient* client_of(std::string_view token) const;

  asio::any_io_executor executor;
  CommandEndpointOptions options;
  RemoteAccess& remote;
  std::shared_ptr<ClientSlots> slots;
  std::shared_ptr<UnixServer> unix_server;
  std::shared_ptr<TcpServer> tcp_server;
  // The sessions being served, for stop(): their pending requests are cancelled there.
  std::map<std::uint64_t, std::weak_ptr<Session>> sessions;
  std::uint64_t next_session = 0;
  CommandEndpointCounters counters;
  std::uint16_t tcp_port = 0;
  std::function<std::string()> stats_json;  // `stats`; empty: not supported
  std::string socket_path;                  // the socket file this endpoint made ("" : none)
  ino_t socket_inode = 0;
  bool started = false;
  bool stopped = false;
  bool warned_full = false;
};

namespace {

// One connected client: a reader that parses and dispatches its lines, a writer that sends the
// answers in the order of the requests, and the client's session settings (`set ...`).
class Session : public std::enable_shared_from_this<Session> {
 public:
  using Core = CommandEndpoint::Core;

  Session(std::shared_ptr<Core> core, std::shared_ptr<Socket> socket, bool tcp, std::string peer)
      : core_(std::move(core)),
        socket_(std::move(socket)),
        wake_(socket_->get_executor(), asio::steady_timer::time_point::max()),
        room_(socket_->get_executor(), asio::steady_timer::time_point::max()),
        authenticated_(!tcp),
        role_(EndpointRole::control),
        peer_(std::move(peer)),
        sdo_timeout_(core_->options.sdo_timeout),
        sdo_block_(core_->options.sdo_block),
        error_detail_(core_->options.error_detail) {}

  // Serves the client until it is closed: the writer runs here, the reader beside it. The
  // client's end is the writer's (after the last answer, or at close()); a reader that threw
  // closes the client, which ends the writer too.
  asio::awaitable<void> run() {
    coro::spawn_owned(socket_->get_executor(), read_loop(),
                      [self = shared_from_this()](const std::string& failure) {
                        if (failure.empty()) return;
                        spdlog::error(
                            "command endpoint: the reader of client {} failed: {}; "
                            "client closed",
                            self->peer_, failure);
                        self->close();
                      });
    co_await write_loop();
  }

  // Ends the client at once: pending requests are cancelled, the monitor feed unsubscribed.
  void close() {
    if (!open_) return;
    open_ = false;
    boost::system::error_code ignored;
    socket_->shutdown(asio::socket_base::shutdown_both, ignored);
    socket_->close(ignored);
    wake_.cancel();
    room_.cancel();
    if (subscription_) {
      core_->remote.unsubscribe(*subscription_);
      subscription_.reset();
    }
    std::vector<RemoteAccess::RequestId> pending;
    for (const auto& reply : replies_) {
      if (reply->request) pending.push_back(*reply->request);
    }
    replies_.clear();
    monitor_lines_.clear();
    for (const auto id : pending) core_->remote.cancel(id);
  }

 private:
  // The answer to one request: lines once done, and the latest progress line meanwhile.
  struct Reply {
    std::optional<std::uint32_t> sequence;
    std::vector<std::string> lines;
    std::string progress;
    bool done = false;
    std::optional<RemoteAccess::RequestId> request;
  };
  using ReplyPtr = std::shared_ptr<Reply>;

  asio::awaitable<void> read_loop() {
    std::string buffer;
    while (open_ && !lingering_) {
      // Pipelined requests beyond the cap wait in the socket, not in memory.
      while (open_ && replies_.size() >= kMaxPipelined) co_await room_.async_wait(kNoError);
      if (!open_) break;
      const std::size_t limit = authenticated_ ? core_->options.max_line_bytes : kPreAuthLineBytes;
      // Room for the line's CR LF beyond its `limit` bytes.
      auto [ec, n] = co_await asio::async_read_until(
          *socket_, asio::dynamic_buffer(buffer, limit + 2), '\n', kNoError);
      if (!open_) break;
      if (ec == asio::error::not_found) {
        linger(
            error_line(std::nullopt, AsciiError::syntax,
                       "line longer than " + std::to_string(limit) + " bytes; connection closed"));
        break;
      }
      if (ec == asio::error::eof) {
        // The client closed its sending side (`printf ... | socat -t 3 - UNIX-CONNECT:...`,
        // docs/remote-access.md): it still waits for the answers to what it sent. A last line
        // without its LF is a request too.
        if (!buffer.empty()) handle_line(buffer);
        stop_reading();
        co_await watch_hangup();
        co_return;
      }
      if (ec) break;  // the socket failed
      std::string_view line(buffer.data(), n - 1);
      handle_line(line);
      buffer.erase(0, n);
    }
    if (!lingering_) close();
  }

  // After the client's end of file, until the writer closes the client: a client that closed
  // its socket altogether (not only its sending side) reads no answer, so its pending requests
  // are cancelled at once rather than run to their end. A Unix socket tells the two apart
  // (POLLHUP); a TCP peer's close looks like a half-close until an answer is written to it, which
  // then fails and closes the client the same way.
  asio::awaitable<void> watch_hangup() {
    while (open_) {
      pollfd p{socket_->native_handle(), POLLRDHUP, 0};
      if (::poll(&p, 1, 0) == 1 && (p.revents & (POLLHUP | POLLERR)) != 0) {
        close();
        co_return;
      }
      // A hang-up or an error wakes every wait on the socket; close() ends this one.
      auto [ec] = co_await socket_->async_wait(Socket::wait_error, kNoError);
      if (ec) co_return;
    }
  }

  asio::awaitable<void> write_loop() {
    std::string batch;
    while (open_) {
      batch.clear();
      take_output(batch);
      if (batch.empty()) {
        if (lingering_ && replies_.empty()) {
          // The last answer is out: tell the client we are done before closing.
          boost::system::error_code ignored;
          socket_->shutdown(asio::socket_base::shutdown_send, ignored);
          break;
        }
        co_await wake_.async_wait(kNoError);
        continue;
      }
      auto [ec, n] = co_await asio::async_write(*socket_, asio::buffer(batch), kNoError);
      if (ec) break;
    }
    close();
  }

  // Moves what may be written now into `batch`: answers in request order (progress of the first
  // unanswered one included), and monitor lines between them.
  void take_output(std::string& batch) {
    while (batch.size() < kWriteBatch) {
      if (!replies_.empty()) {
        Reply& front = *replies_.front();
        if (!front.progress.empty()) {
          batch += front.progress;
          front.progress.clear();
        }
        if (front.done) {
          for (const auto& line : front.lines) batch += line;
          replies_.pop_front();
          room_.cancel();
          continue;
        }
      }
      if (!monitor_lines_.empty()) {
        batch += monitor_lines_.front();
        monitor_lines_.pop_front();
        continue;
      }
      if (monitor_dropped_ > 0) {
        batch += "DROPPED " + std::to_string(monitor_dropped_) + "\r\n";
        monitor_dropped_ = 0;
        continue;
      }
      break;
    }
  }

  // Says `line` as the last answer and closes once everything before it is written.
  void linger(std::string line, std::optional<std::uint32_t> sequence = std::nullopt) {
    ReplyPtr reply = new_reply(sequence);
    finish(reply, std::move(line));
    stop_reading();
  }

  // Reads nothing more: the requests already read are answered, then the client is closed. A
  // monitor feed ends here (it has no last answer to wait for).
  void stop_reading() {
    lingering_ = true;
    if (subscription_) {
      core_->remote.unsubscribe(*subscription_);
      subscription_.reset();
      monitor_lines_.clear();
    }
    wake_.cancel();  // the writer may be done already
  }

  ReplyPtr new_reply(std::optional<std::uint32_t> sequence) {
    auto reply = std::make_shared<Reply>();
    reply->sequence = sequence;
    replies_.push_back(reply);
    return reply;
  }

  void finish(const ReplyPtr& reply, std::string line) {
    const std::size_t prefix =
        reply->sequence ? std::to_string(*reply->sequence).size() + 3 : 0;  // "[<seq>] "
    if (line.size() > prefix && line.compare(prefix, 6, "ERROR:") == 0) {
      ++core_->counters.errors;
    }
    reply->lines.push_back(std::move(line));
    reply->done = true;
    reply->request.reset();
    wake_.cancel();
  }

  // An error line, with canbridge's reason after the reference text if the session wants it.
  std::string error_line(std::optional<std::uint32_t> sequence, AsciiError error,
                         std::string_view detail = {}) const {
    return canopen::ascii_error(sequence, error, error_detail_ ? detail : std::string_view());
  }

  void fail(const ReplyPtr& reply, AsciiError error, std::string_view detail = {}) {
    finish(reply, error_line(reply->sequence, error, detail));
  }

  // The completion of a RemoteAccess call: a no-op once the client is gone.
  template <typename OnOutcome>
  auto completion(const ReplyPtr& reply, OnOutcome on_outcome) {
    return [weak = weak_from_this(), reply, on_outcome](RemoteOutcome outcome) {
      const auto self = weak.lock();
      if (!self || !self->open_) return;
      if (!outcome.ok()) {
        self->finish(reply, failure_text(reply->sequence, outcome, self->error_detail_));
      } else {
        self->finish(reply, on_outcome(outcome));
      }
    };
  }

  auto ok_completion(const ReplyPtr& reply) {
    return completion(
        reply, [seq = reply->sequence](const RemoteOutcome&) { return canopen::ascii_ok(seq); });
  }

  void handle_line(std::string_view line) {
    canopen::AsciiParse parse = canopen::parse_ascii_command(line);
    AsciiCommand& cmd = parse.command;
    if (parse.ok() && cmd.verb == AsciiVerb::none) {
      // A blank or comment-only line: CANopenNode's gateway answers it with an empty line (CR LF
      // alone), in its place among the answers, and a client that reads one answer per line it
      // sent (cocomm) waits for it. Before a TCP client's `auth` it is skipped.
      if (authenticated_) finish(new_reply(std::nullopt), "\r\n");
      return;
    }
    ++core_->counters.commands;
    if (!authenticated_) {
      if (!parse.ok() || cmd.verb != AsciiVerb::auth) {
        ++core_->counters.auth_failures;
        linger(error_line(cmd.sequence, AsciiError::authentication_required), cmd.sequence);
        return;
      }
      return authenticate(cmd);
    }
    ReplyPtr reply = new_reply(cmd.sequence);
    if (!parse.ok()) return fail(reply, *parse.error, parse.detail);
    if (role_ == EndpointRole::monitor && !allowed_for_monitor(cmd.verb)) {
      ++core_->counters.refused;
      if (!warned_refused_) {
        warned_refused_ = true;
        spdlog::warn(
            "command endpoint: client {} (role monitor) asked for a control request; refused "
            "(further refusals of this client are only counted)",
            peer_);
      }
      return fail(reply, AsciiError::not_permitted);
    }
    dispatch(reply, cmd);
  }

  void authenticate(const AsciiCommand& cmd) {
    const EndpointClient* client = core_->client_of(cmd.text);
    if (client == nullptr) {
      ++core_->counters.auth_failures;
      spdlog::warn("command endpoint: TCP client {} sent a wrong token; closed", peer_);
      linger(error_line(cmd.sequence, AsciiError::authentication_required, "wrong token"),
             cmd.sequence);
      return;
    }
    ReplyPtr reply = new_reply(cmd.sequence);
    authenticated_ = true;
    role_ = client->role;
    spdlog::info("command endpoint: TCP client {} authenticated as {} ({})", peer_, client->name,
                 client->role == EndpointRole::control ? "control" : "monitor");
    peer_ = client->name + "@" + peer_;
    finish(reply, canopen::ascii_ok(reply->sequence));
  }

  // The network of a command (written, or the session's default) if the surface knows it.
  std::optional<NetworkNumber> network(const AsciiCommand& cmd, const ReplyPtr& reply) {
    const NetworkNumber net = cmd.net.value_or(net_default_);
    if (net != 0 && !find_network(net)) {
      fail(reply, AsciiError::unsupported_net, "net " + std::to_string(net));
      return std::nullopt;
    }
    return net;
  }

  std::optional<NetworkInfo> find_network(NetworkNumber net) const {
    for (const auto& info : core_->remote.networks()) {
      if (info.net == net) return info;
    }
    return std::nullopt;
  }

  // Network and node of a node command; `min_node` 0 lets NMT address every node.
  std::optional<RemoteTarget> target(const AsciiCommand& cmd, const ReplyPtr& reply,
                                     std::uint32_t min_node) {
    const auto net = network(cmd, reply);
    if (!net) return std::nullopt;
    const auto node = cmd.node ? cmd.node : node_default_;
    if (!node) {
      fail(reply, AsciiError::no_default_node);
      return std::nullopt;
    }
    if (*node < min_node) {
      fail(reply, AsciiError::unsupported_node, "node " + std::to_string(*node));
      return std::nullopt;
    }
    return RemoteTarget{*net, static_cast<canopen::NodeId>(*node)};
  }

  void dispatch(const ReplyPtr& reply, const AsciiCommand& cmd) {
    RemoteAccess& remote = core_->remote;
    const auto seq = reply->sequence;
    switch (cmd.verb) {
      case AsciiVerb::none:
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::auth:
        // Unix socket clients are control already: the socket file's mode decides.
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::read:
      case AsciiVerb::write: {
        const auto where = target(cmd, reply, 1);
        if (!where) return;
        RemoteSdo sdo;
        sdo.target = *where;
        sdo.index = cmd.index;
        sdo.sub = cmd.sub;
        sdo.upload = cmd.verb == AsciiVerb::read;
        sdo.data = cmd.value;
        sdo.timeout = sdo_timeout_;
        sdo.block_size = sdo_block_ ? kBlockSize : 0;
        if (sdo.upload) {
          const auto type = cmd.type.value_or(canopen::AsciiType::hex);
          reply->request = remote.sdo(
              std::move(sdo), completion(reply, [seq, type](const RemoteOutcome& o) {
                return canopen::ascii_line(seq, canopen::format_ascii_value(type, o.data));
              }));
        } else {
          reply->request = remote.sdo(std::move(sdo), ok_completion(reply));
        }
        return;
      }
      case AsciiVerb::nmt: {
        const auto where = target(cmd, reply, 0);
        if (!where) return;
        reply->request = remote.nmt(*where, to_nmt(cmd.nmt), ok_completion(reply));
        return;
      }
      case AsciiVerb::set_node_id: {
        const auto where = target(cmd, reply, 1);
        if (!where) return;
        // The answer is the surface id the node has now, from the gateway's live map after the
        // rename ("-": none): the new id is a local one, and the map may keep the node at its
        // surface id. A gateway that does not say (an older one) is answered OK.
        reply->request = remote.set_node_id(
            *where, static_cast<canopen::NodeId>(cmd.number),
            completion(reply, [seq](const RemoteOutcome& o) {
              if (o.data.size() != 1) return canopen::ascii_ok(seq);
              return canopen::ascii_line(seq, o.data[0] == 0 ? "-" : std::to_string(o.data[0]));
            }));
        return;
      }
      case AsciiVerb::flash:
        return flash(reply, cmd);
      case AsciiVerb::set_network:
        if (cmd.number != 0 && !find_network(cmd.number)) {
          return fail(reply, AsciiError::unsupported_net, "net " + std::to_string(cmd.number));
        }
        net_default_ = cmd.number;
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::set_node:
        if (!network(cmd, reply)) return;
        node_default_ = cmd.number;
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::set_sdo_timeout:
        if (!network(cmd, reply)) return;
        sdo_timeout_ = std::chrono::milliseconds(cmd.number);
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::set_sdo_block:
        if (!network(cmd, reply)) return;
        sdo_block_ = cmd.number != 0;
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::set_error_detail:
        if (!network(cmd, reply)) return;
        error_detail_ = cmd.number != 0;
        return finish(reply, canopen::ascii_ok(seq));
      case AsciiVerb::help:
        return finish(reply, canopen::ascii_multiline(seq, canopen::ascii_help(cmd.text)));
      case AsciiVerb::nodes:
        return nodes(reply, cmd);
      case AsciiVerb::monitor:
        return monitor(reply, cmd);
      case AsciiVerb::lss:
        return lss(reply, cmd);
      case AsciiVerb::stats:
        if (!core_->stats_json) {
          return fail(reply, AsciiError::request_not_supported, "stats: not served here");
        }
        reply->lines.push_back(canopen::ascii_line(seq, core_->stats_json()));
        return finish(reply, canopen::ascii_ok(seq));
    }
  }

  void flash(const ReplyPtr& reply, const AsciiCommand& cmd) {
    const auto where = target(cmd, reply, 1);
    if (!where) return;
    std::vector<std::uint8_t> image;
    if (auto problem = read_image(cmd.text, image)) {
      return fail(reply, AsciiError::internal_state, "flash: " + *problem);
    }
    auto progress = [weak = weak_from_this(), reply](const FlashProgress& p) {
      const auto self = weak.lock();
      if (!self || !self->open_ || reply->done) return;
      // Latest wins: a reply not yet first in line keeps only its newest progress line.
      reply->progress = canopen::ascii_line(
          reply->sequence, "PROGRESS " + p.step + " " + std::to_string(p.bytes_done) + " " +
                               std::to_string(p.bytes_total));
      self->wake_.cancel();
    };
    reply->request =
        core_->remote.flash(*where, std::move(image), std::move(progress), ok_completion(reply));
  }

  // Reads a firmware image on the surface; why not, for the operator.
  static std::optional<std::string> read_image(const std::string& path,
                                               std::vector<std::uint8_t>& image) {
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
      return "cannot read " + path + ": " + std::strerror(errno);
    }
    if (!S_ISREG(st.st_mode)) return path + " is not a regular file";
    if (static_cast<std::uintmax_t>(st.st_size) > kMaxImageBytes) {
      return path + " is larger than " + std::to_string(kMaxImageBytes) + " bytes";
    }
    std::ifstream file(path, std::ios::binary);
    if (!file) return "cannot read " + path + ": " + std::strerror(errno);
    image.assign(std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>());
    if (file.bad()) return "cannot read " + path + ": read failed";
    if (image.empty()) return path + " is empty";
    return std::nullopt;
  }

  void nodes(const ReplyPtr& reply, const AsciiCommand& cmd) {
    const auto net = network(cmd, reply);
    if (!net) return;
    core_->remote.nodes(*net, [weak = weak_from_this(), reply, net = *net](
                                  std::vector<NodeRow> rows, std::error_code error) {
      const auto self = weak.lock();
      if (!self || !self->open_) return;
      if (error) {
        self->finish(reply, failure_text(reply->sequence, RemoteOutcome{error, {}, {}},
                                         self->error_detail_));
        return;
      }
      // One multi-line answer (canopen::ascii_multiline): rows separated by LF, one CR LF after
      // the closing OK, so that cocomm prints every row; each row keeps its `[<seq>] ` prefix,
      // which line-based clients (canbridge nodes) match.
      const std::string prefix = canopen::ascii_prefix(reply->sequence);
      std::vector<std::string> lines;
      for (const auto& row : rows) lines.push_back(prefix + node_line(row));
      // The rows of a gateway that is down are the surface's own (each lost): say which.
      for (const auto& gateway : self->gateways_down(net)) {
        lines.push_back(prefix + "gateway name=" + gateway + " state=down");
      }
      self->finish(reply, canopen::ascii_multiline(reply->sequence, lines));
    });
  }

  // The configured gateways of network `net` (0: of every network) that are not connected now.
  std::vector<std::string> gateways_down(NetworkNumber net) const {
    std::vector<std::string> down;
    for (const auto& info : core_->remote.networks()) {
      if (info.net == 0 || info.connected || (net != 0 && info.net != net)) continue;
      if (std::find(down.begin(), down.end(), info.gateway) == down.end()) {
        down.push_back(info.gateway);
      }
    }
    return down;
  }

  void monitor(const ReplyPtr& reply, const AsciiCommand& cmd) {
    monitor_module_ = cmd.module;
    if (!subscription_) {
      subscription_ = core_->remote.subscribe([weak = weak_from_this()](const MonitorFrame& frame) {
        if (const auto self = weak.lock()) self->on_frame(frame);
      });
    }
    finish(reply, canopen::ascii_ok(reply->sequence));
  }

  void on_frame(const MonitorFrame& frame) {
    if (!open_ || lingering_) return;
    if (monitor_module_ && frame.module_id != *monitor_module_) return;
    if (monitor_lines_.size() >= core_->options.monitor_queue_frames) {
      ++monitor_dropped_;
      ++core_->counters.monitor_dropped;
      return;
    }
    // Frames lost before this one are told first, in their place.
    if (monitor_dropped_ > 0) {
      monitor_lines_.push_back("DROPPED " + std::to_string(monitor_dropped_) + "\r\n");
      monitor_dropped_ = 0;
    }
    monitor_lines_.push_back(frame_line(frame));
    wake_.cancel();
  }

  void lss(const ReplyPtr& reply, const AsciiCommand& cmd) {
    const auto net = network(cmd, reply);
    if (!net) return;
    const auto info = find_network(*net);
    if (!info || !info->lss) {
      return fail(reply, AsciiError::request_not_supported,
                  "no LSS on net " + std::to_string(*net));
    }
    const bool inquiry = cmd.text == "lss_get_node" || cmd.text == "lss_inquire_addr";
    auto on_ok = [seq = reply->sequence, inquiry, command = cmd.text](const RemoteOutcome& o) {
      return inquiry ? canopen::ascii_line(seq, lss_answer(command, o.data))
                     : canopen::ascii_ok(seq);
    };
    reply->request = core_->remote.lss(*net, cmd.text, cmd.args, completion(reply, on_ok));
  }

  std::shared_ptr<Core> core_;
  std::shared_ptr<Socket> socket_;
  asio::steady_timer wake_;  // wakes the writer: something to write, or closing
  asio::steady_timer room_;  // wakes the reader: an answer went out
  std::deque<ReplyPtr> replies_;
  std::deque<std::string> monitor_lines_;
  std::uint64_t monitor_dropped_ = 0;  // not yet told to the client
  std::optional<std::uint64_t> subscription_;
  std::optional<std::uint32_t> monitor_module_;
  bool authenticated_;  // Unix socket clients are; TCP clients after `auth`
  EndpointRole role_;
  std::string peer_;
  NetworkNumber net_default_ = 0;
  std::optional<std::uint32_t> node_default_;
  std::chrono::milliseconds sdo_timeout_;
  bool sdo_block_;
  bool error_detail_;
  bool open_ = true;
  bool lingering_ = false;  // answers the rest, then closes; reads nothing more
  bool warned_refused_ = false;
};

}  // namespace

void CommandEndpoint::Core::start() {
  if (started || stopped) throw std::runtime_error("command endpoint: started twice");
  started = true;
  if (!options.unix_socket.empty()) listen_unix();
  if (options.tcp_port != 0) listen_tcp();
  // Accepting starts once every listener is bound: a failed one leaves none serving.
  if (unix_server) unix_server->start();
  if (tcp_server) tcp_server->start();
}

void CommandEndpoint::Core::listen_unix() {
  const auto& path = options.unix_socket;
  unix_server = std::make_shared<UnixServer>(
      executor, "command endpoint (" + path + ")", slots,
      [weak = weak_from_this()](std::shared_ptr<Socket> socket) {
        return serve(weak.lock(), std::move(socket), false);
      },
      [weak = weak_from_this()](Local::socket& socket) {
        if (const auto self = weak.lock()) self->refuse(socket, "on " + self->options.unix_socket);
      });
  Local::acceptor& acceptor = unix_server->acceptor();
  boost::system::error_code ec;
  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (!S_ISSOCK(st.st_mode)) {
      throw std::runtime_error("command endpoint: " + path +
                               " exists and is not a socket; refusing to replace it");
    }
    // A socket file someone still serves is not stale: two surfaces must not share it.
    Local::socket probe(executor);
    probe.connect(Local::endpoint(path), ec);
    if (!ec) throw std::runtime_error("command endpoint: another process serves " + path);
    ::unlink(path.c_str());
  }
  acceptor.open(Local(), ec);
  if (!ec) acceptor.bind(Local::endpoint(path), ec);
  if (ec) throw std::runtime_error("command endpoint: cannot bind " + path + ": " + ec.message());
  socket_path = path;
  if (::lstat(path.c_str(), &st) == 0) socket_inode = st.st_ino;
  // Before listen(): nobody can connect while the mode is still the umask's.
  if (::chmod(path.c_str(), 0660) != 0) {
    throw std::runtime_error("command endpoint: cannot chmod " + path + ": " +
                             std::strerror(errno));
  }
  acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) {
    throw std::runtime_error("command endpoint: cannot listen on " + path + ": " + ec.message());
  }
  spdlog::info("command endpoint: listening on {}", path);
}

void CommandEndpoint::Core::listen_tcp() {
  boost::system::error_code ec;
  const auto address = asio::ip::make_address(options.tcp_address, ec);
  if (ec) {
    throw std::runtime_error("command endpoint: tcp_address " + options.tcp_address +
                             " is not an IP address");
  }
  if (!address.is_loopback()) {
    throw std::runtime_error("command endpoint: tcp_address " + options.tcp_address +
                             " is not a loopback address; the TCP endpoint only listens on "
                             "loopback (docs/security.md)");
  }
  tcp_server = std::make_shared<TcpServer>(
      executor, "command endpoint (TCP)", slots,
      [weak = weak_from_this()](std::shared_ptr<Socket> socket) {
        return serve(weak.lock(), std::move(socket), true);
      },
      [weak = weak_from_this()](Tcp::socket& socket) {
        boost::system::error_code ignored;
        const auto peer = socket.remote_endpoint(ignored);
        if (const auto self = weak.lock()) {
          self->refuse(socket, peer.address().to_string() + ":" + std::to_string(peer.port()));
        }
      });
  Tcp::acceptor& acceptor = tcp_server->acceptor();
  const Tcp::endpoint endpoint(address, options.tcp_port);
  acceptor.open(endpoint.protocol(), ec);
  if (!ec) acceptor.set_option(Tcp::acceptor::reuse_address(true), ec);
  if (!ec) acceptor.bind(endpoint, ec);
  if (!ec) acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (!ec) tcp_port = acceptor.local_endpoint(ec).port();
  if (ec) {
    throw std::runtime_error("command endpoint: cannot listen on " + options.tcp_address + ":" +
                             std::to_string(options.tcp_port) + ": " + ec.message());
  }
  if (options.clients.empty()) {
    spdlog::warn("command endpoint: TCP on port {} has no clients: every auth fails", tcp_port);
  }
  spdlog::info("command endpoint: listening on {}:{}", options.tcp_address, tcp_port);
}

void CommandEndpoint::Core::stop() {
  if (stopped) return;
  stopped = true;
  // Each client's pending requests are cancelled before its socket goes: close() does both.
  for (const auto& [id, weak] : std::map(sessions)) {
    if (const auto session = weak.lock()) session->close();
  }
  if (unix_server) unix_server->stop();
  if (tcp_server) tcp_server->stop();
  // Only the file this endpoint made: a successor may have replaced it already.
  struct stat st {};
  if (!socket_path.empty() && ::lstat(socket_path.c_str(), &st) == 0 && st.st_ino == socket_inode &&
      S_ISSOCK(st.st_mode)) {
    ::unlink(socket_path.c_str());
  }
}

asio::awaitable<void> CommandEndpoint::Core::serve(std::shared_ptr<Core> self,
                                                   std::shared_ptr<Socket> socket, bool tcp) {
  if (!self || self->stopped) co_return;
  const std::uint64_t id = ++self->next_session;
  std::string peer = "unix#" + std::to_string(id);
  if (tcp) {
    // The generic socket's address is a TCP one: read it back as such, for the logs.
    boost::system::error_code ignored;
    const auto generic = socket->remote_endpoint(ignored);
    Tcp::endpoint remote_end;
    if (!ignored && generic.size() <= remote_end.capacity()) {
      std::memcpy(remote_end.data(), generic.data(), generic.size());
      remote_end.resize(generic.size());
      peer = remote_end.address().to_string() + ":" + std::to_string(remote_end.port());
    }
  }
  ++self->counters.clients;
  spdlog::debug("command endpoint: client {} connected", peer);
  const auto session = std::make_shared<Session>(self, std::move(socket), tcp, peer);
  self->sessions.emplace(id, session);
  // However the session ends (even by an exception), its requests are cancelled and stop()
  // forgets it.
  struct Forget {
    Core& core;
    std::uint64_t id;
    Session& session;
    ~Forget() {
      session.close();
      core.sessions.erase(id);
    }
  } forget{*self, id, *session};
  co_await session->run();
}

template <typename Fresh>
void CommandEndpoint::Core::refuse(Fresh& socket, const std::string& peer) {
  ++counters.clients_refused;
  if (!warned_full) {
    warned_full = true;
    spdlog::warn(
        "command endpoint: {} clients connected (max_clients): client {} refused (further "
        "refusals are only counted)",
        options.max_clients, peer);
  }
  const std::string line = canopen::ascii_error(
      std::nullopt, AsciiError::internal_state,
      options.error_detail ? "too many clients (" + std::to_string(options.max_clients) + ")"
                           : std::string());
  boost::system::error_code ignored;
  asio::write(socket, asio::buffer(line), ignored);  // a few bytes on a fresh socket
}

const EndpointClient* CommandEndpoint::Core::client_of(std::string_view token) const {
  const EndpointClient* found = nullptr;
  for (const auto& client : options.clients) {
    // No early exit: the time taken does not tell which client (or whether any) matched.
    const bool match = !client.token.empty() && same_token(client.token, token);
    if (match && found == nullptr) found = &client;
  }
  return found;
}

CommandEndpoint::CommandEndpoint(asio::any_io_executor executor, CommandEndpointOptions options,
                                 RemoteAccess& remote)
    : core_(std::make_shared<Core>(std::move(executor), std::move(options), remote)) {}

CommandEndpoint::~CommandEndpoint() {
  core_->stop();
}

void CommandEndpoint::serve_stats(std::function<std::string()> json) {
  core_->stats_json = std::move(json);
}

void CommandEndpoint::start() {
  try {
    core_->start();
  } catch (...) {
    core_->stop();
    throw;
  }
}

void CommandEndpoint::stop() {
  core_->stop();
}

std::uint16_t CommandEndpoint::tcp_port() const {
  return core_->tcp_port;
}

CommandEndpointCounters CommandEndpoint::counters() const {
  CommandEndpointCounters counters = core_->counters;
  counters.sessions = core_->slots->used;
  return counters;
}

}  // namespace canbridge::bridge
