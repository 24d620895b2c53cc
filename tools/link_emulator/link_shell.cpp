#include "tools/link_emulator/link_shell.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <csignal>
#include <cstdio>
#include <exception>
#include <list>
#include <memory>
#include <optional>
#include <tuple>
#include <vector>

#include "coro/no_error.hpp"
#include "tools/link_emulator/impairment.hpp"
#include "tools/link_emulator/pty_endpoint.hpp"

namespace canbridge::emulator {

namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using namespace std::chrono_literals;

using canbridge::coro::kNoError;
// Pause before a connect side that nothing drives (its peer is a pty or connects itself) tries
// again, and after an unexpected error, so that failures do not spin.
constexpr auto kReconnectDelay = 250ms;
constexpr auto kErrorPause = 100ms;
constexpr std::size_t kReadChunk = 64 * 1024;

// stdout carries the lines tests wait for; flushed at once because it is usually a pipe.
void print_line(const std::string& line) {
  std::fputs((line + "\n").c_str(), stdout);
  std::fflush(stdout);
}

// One endpoint: where bytes come from and go to, and whether that is possible right now.
struct Side {
  Side(asio::io_context& io, std::string side_name, EndpointSpec endpoint)
      : name(std::move(side_name)), spec(std::move(endpoint)), socket(io) {}

  bool is_tcp() const { return spec.kind != EndpointSpec::Kind::pty; }

  std::string name;  // "a" or "b"
  EndpointSpec spec;
  std::string resolved;  // for the ready line
  std::optional<tcp::acceptor> acceptor;
  tcp::endpoint remote;  // tcp-connect
  tcp::socket socket;
  std::unique_ptr<PtyEndpoint> pty;
  // A pty is always up; a TCP side while it has a connection.
  bool up = false;
  // Bumped whenever the connection changes, so a completion from a connection that has been
  // replaced or closed meanwhile is recognised and ignored.
  std::uint64_t generation = 0;
  TimePoint retry_at{};
  bool connect_failure_reported = false;
  // The connection ended during a silent cut: its end is passed on only after the cut, once what
  // it sent before has been delivered (TCP data before a FIN arrives when the route returns).
  bool closed_in_silent_cut = false;
};

class Shell {
 public:
  Shell(asio::io_context& io, const EmulatorOptions& options)
      : io_(io),
        options_(options),
        a_(io, "a", options.a),
        b_(io, "b", options.b),
        a_to_b_(options.a_to_b()),
        b_to_a_(options.b_to_a()) {
    open(a_);
    open(b_);
  }

  void start() {
    origin_ = Clock::now();
    print_line(format_ready_line(a_.resolved, b_.resolved));
    spawn(side_loop(a_, b_));
    spawn(side_loop(b_, a_));
    spawn(read_loop(a_, a_to_b_));
    spawn(write_loop(b_, a_to_b_));
    spawn(read_loop(b_, b_to_a_));
    spawn(write_loop(a_, b_to_a_));
    if (!options_.cuts.empty()) spawn(cut_loop());
    if (options_.stats_interval > 0s) spawn(stats_loop());
  }

  // Ends every loop; io_context::run() returns once they have unwound.
  void stop() {
    if (stopping_) return;
    stopping_ = true;
    print_line(format_stats("final stats", a_to_b_.counters(), b_to_a_.counters()));
    for (Side* side : {&a_, &b_}) {
      boost::system::error_code ignored;
      if (side->acceptor) side->acceptor->close(ignored);
      side->socket.close(ignored);
      if (side->pty) side->pty->master().cancel(ignored);
    }
    poke();
  }

 private:
  void open(Side& side) {
    switch (side.spec.kind) {
      case EndpointSpec::Kind::tcp_listen: {
        tcp::resolver resolver(io_);
        const tcp::endpoint endpoint =
            resolver.resolve(side.spec.host, std::to_string(side.spec.port), tcp::resolver::passive)
                .begin()
                ->endpoint();
        side.acceptor.emplace(io_);
        side.acceptor->open(endpoint.protocol());
        side.acceptor->set_option(tcp::acceptor::reuse_address(true));
        side.acceptor->bind(endpoint);
        side.acceptor->listen();
        EndpointSpec bound = side.spec;
        bound.host = endpoint.address().to_string();
        bound.port = side.acceptor->local_endpoint().port();
        side.resolved = to_string(bound);
        break;
      }
      case EndpointSpec::Kind::tcp_connect: {
        tcp::resolver resolver(io_);
        side.remote =
            resolver.resolve(side.spec.host, std::to_string(side.spec.port)).begin()->endpoint();
        EndpointSpec target = side.spec;
        target.host = side.remote.address().to_string();
        side.resolved = to_string(target);
        break;
      }
      case EndpointSpec::Kind::pty:
        side.pty = std::make_unique<PtyEndpoint>(io_, side.spec.path);
        side.up = true;
        side.resolved = to_string(side.spec) + "->" + side.pty->device();
        break;
    }
  }

  void spawn(asio::awaitable<void> loop) {
    // A throwing loop is a programming error: let it surface from io_context::run().
    asio::co_spawn(io_, std::move(loop), [](std::exception_ptr error) {
      if (error) std::rethrow_exception(error);
    });
  }

  // Every loop sleeps on its own timer; any change of state cancels them all and each loop
  // re-checks what it waits for. Single-threaded, so no wakeup is lost: a loop checks its
  // condition and starts waiting without anything running in between.
  bool silent_cut() const {
    return in_cut_ && options_.cut_mode == EmulatorOptions::CutMode::silent;
  }
  // A TCP side during a silent cut: its connection stays, nothing is read from or written to it.
  bool frozen_side(const Side& side) const { return silent_cut() && side.is_tcp(); }

  asio::steady_timer& new_waiter() { return waiters_.emplace_back(io_); }
  void poke() {
    for (auto& timer : waiters_) timer.cancel();
  }
  asio::awaitable<void> sleep(asio::steady_timer& timer, TimePoint deadline) {
    timer.expires_at(deadline);
    co_await timer.async_wait(kNoError);
  }
  // Unlike sleep(), not ended early by poke().
  asio::awaitable<void> sleep_until(asio::steady_timer& timer, TimePoint deadline) {
    while (!stopping_ && Clock::now() < deadline) co_await sleep(timer, deadline);
  }

  // Closes every TCP connection and throws away what the line holds in both directions: either
  // end of one TCP connection going away ends the end-to-end session, as with a direct
  // connection.
  void drop_connections(DiscardReason reason) {
    for (Side* side : {&a_, &b_}) {
      if (!side->is_tcp()) continue;
      boost::system::error_code ignored;
      side->socket.close(ignored);  // also aborts a connect in progress
      side->closed_in_silent_cut = false;
      if (side->up) {
        side->up = false;
        ++side->generation;
        side->retry_at = Clock::now() + kReconnectDelay;
      }
    }
    const TimePoint now = Clock::now();
    a_to_b_.discard_held(reason, now);
    b_to_a_.discard_held(reason, now);
    poke();
  }

  void connection_up(Side& side) {
    boost::system::error_code ignored;
    side.socket.set_option(tcp::no_delay(true), ignored);
    side.up = true;
    side.closed_in_silent_cut = false;
    ++side.generation;
    poke();
  }

  asio::awaitable<void> side_loop(Side& self, Side& peer) {
    if (self.spec.kind == EndpointSpec::Kind::tcp_listen) co_await accept_loop(self);
    if (self.spec.kind == EndpointSpec::Kind::tcp_connect) co_await connect_loop(self, peer);
  }

  asio::awaitable<void> accept_loop(Side& self) {
    asio::steady_timer& timer = new_waiter();
    bool refusal_reported = false;
    while (!stopping_) {
      auto [ec, socket] = co_await self.acceptor->async_accept(kNoError);
      if (stopping_) break;
      if (ec) {
        spdlog::warn("{}: accept failed: {}", self.name, ec.message());
        co_await sleep(timer, Clock::now() + kErrorPause);
        continue;
      }
      // A silent cut: the new connection waits, unserved, until the route is back.
      while (silent_cut() && !stopping_) co_await sleep(timer, TimePoint::max());
      if (stopping_) break;
      if (in_cut_) {
        // The wire is broken: the caller sees its connection end at once.
        if (!refusal_reported) spdlog::info("{}: refusing connections during the cut", self.name);
        refusal_reported = true;
        boost::system::error_code ignored;
        socket.close(ignored);
        continue;
      }
      refusal_reported = false;
      if (self.up) {
        spdlog::info("{}: a new connection replaces the current one", self.name);
        drop_connections(DiscardReason::disconnect);
      }
      boost::system::error_code ignored;
      const auto from = socket.remote_endpoint(ignored);
      spdlog::info("{}: accepted {}:{}", self.name, from.address().to_string(), from.port());
      self.socket = std::move(socket);
      connection_up(self);
    }
  }

  // Connects when the peer is a listener that has a connection (once per peer connection), or
  // on its own and again after every failure when the peer is a pty or connects by itself.
  asio::awaitable<void> connect_loop(Side& self, Side& peer) {
    asio::steady_timer& timer = new_waiter();
    const bool peer_driven = peer.spec.kind == EndpointSpec::Kind::tcp_listen;
    while (!stopping_) {
      const bool wanted = !in_cut_ && !self.up && (!peer_driven || peer.up);
      if (!wanted) {
        co_await sleep(timer, TimePoint::max());
        continue;
      }
      if (!peer_driven && Clock::now() < self.retry_at) {
        co_await sleep(timer, self.retry_at);
        continue;
      }
      const std::uint64_t peer_generation = peer.generation;
      self.socket = tcp::socket(io_);
      auto [ec] = co_await self.socket.async_connect(self.remote, kNoError);
      if (stopping_) break;
      const bool peer_unchanged = !peer_driven || (peer.up && peer.generation == peer_generation);
      if (!ec && !in_cut_ && peer_unchanged) {
        spdlog::info("{}: connected to {}", self.name, self.resolved);
        self.connect_failure_reported = false;
        connection_up(self);
        continue;
      }
      boost::system::error_code ignored;
      self.socket.close(ignored);
      if (!ec || ec == asio::error::operation_aborted) continue;  // the situation changed
      if (!self.connect_failure_reported) {
        spdlog::warn("{}: cannot connect to {}: {}", self.name, self.resolved, ec.message());
      }
      self.connect_failure_reported = true;
      self.retry_at = Clock::now() + kReconnectDelay;
      // The far end is unreachable: so is it for the one that connected to the peer.
      if (peer_driven && peer_unchanged) drop_connections(DiscardReason::disconnect);
    }
  }

  asio::awaitable<std::tuple<boost::system::error_code, std::size_t>> read_some(
      Side& side, asio::mutable_buffer buffer) {
    if (side.pty) co_return co_await side.pty->master().async_read_some(buffer, kNoError);
    co_return co_await side.socket.async_read_some(buffer, kNoError);
  }

  asio::awaitable<std::tuple<boost::system::error_code, std::size_t>> write_all(
      Side& side, asio::const_buffer buffer) {
    if (side.pty) co_return co_await asio::async_write(side.pty->master(), buffer, kNoError);
    co_return co_await asio::async_write(side.socket, buffer, kNoError);
  }

  // Reads `from` into `line`, no more than the line has room for (back-pressure); during a cut
  // reads and discards.
  asio::awaitable<void> read_loop(Side& from, Impairment& line) {
    asio::steady_timer& timer = new_waiter();
    std::vector<std::uint8_t> buffer(kReadChunk);
    while (!stopping_) {
      if (from.closed_in_silent_cut && !in_cut_ && line.held() == 0) {
        // The route is back and what this side sent before it closed has been delivered.
        spdlog::info("{}: connection closed during the silent cut", from.name);
        drop_connections(DiscardReason::disconnect);
        continue;
      }
      const bool frozen = frozen_side(from) || from.closed_in_silent_cut;
      if (!from.up || frozen || (!in_cut_ && line.free_space() == 0)) {
        co_await sleep(timer, TimePoint::max());
        continue;
      }
      const std::uint64_t generation = from.generation;
      const std::size_t room = in_cut_ ? buffer.size() : std::min(buffer.size(), line.free_space());
      auto [ec, n] = co_await read_some(from, asio::buffer(buffer.data(), room));
      if (stopping_) break;
      if (generation != from.generation) continue;  // that connection is gone
      if (ec && frozen_side(from)) {
        from.closed_in_silent_cut = true;  // the other end learns of it after the cut
        continue;
      }
      if (ec) {
        if (from.is_tcp()) {
          spdlog::info("{}: connection closed: {}", from.name, ec.message());
          drop_connections(DiscardReason::disconnect);
        } else {
          spdlog::warn("{}: reading the pty failed: {}", from.name, ec.message());
          co_await sleep(timer, Clock::now() + kErrorPause);
        }
        continue;
      }
      if (in_cut_ && !frozen_side(from)) {
        line.count_dropped_in_cut(n);
      } else {  // (a read that was under way when a silent cut began: held, delivered after it)
        // Only this loop pushes and it read at most free_space(), so everything fits.
        line.push(std::span<const std::uint8_t>(buffer.data(), n), Clock::now());
      }
      poke();
    }
  }

  // Writes what `line` has due to `to`, at the time it is due.
  asio::awaitable<void> write_loop(Side& to, Impairment& line) {
    asio::steady_timer& timer = new_waiter();
    std::string due;
    while (!stopping_) {
      if (to.closed_in_silent_cut && !in_cut_ && line.held() > 0) {
        // Nobody left to receive it: the connection's end is passed on by the other side's reader.
        line.discard_held(DiscardReason::disconnect, Clock::now());
        poke();
        continue;
      }
      if (!to.up || line.held() == 0 || frozen_side(to) || to.closed_in_silent_cut) {
        co_await sleep(timer, TimePoint::max());
        continue;
      }
      if (Clock::now() < line.next_delivery()) {
        co_await sleep(timer, line.next_delivery());
        continue;
      }
      due.clear();
      line.pop_due(Clock::now(), due);
      poke();  // room for the reader again
      const std::uint64_t generation = to.generation;
      auto [ec, n] = co_await write_all(to, asio::buffer(due));
      if (stopping_) break;
      if (generation != to.generation || !ec) continue;
      if (to.is_tcp()) {
        spdlog::info("{}: connection closed while writing: {}", to.name, ec.message());
        drop_connections(DiscardReason::disconnect);
      } else {
        spdlog::warn("{}: writing the pty failed: {}", to.name, ec.message());
        co_await sleep(timer, Clock::now() + kErrorPause);
      }
    }
  }

  asio::awaitable<void> cut_loop() {
    asio::steady_timer& timer = new_waiter();
    const auto& cuts = options_.cuts.cuts();
    const std::string of = "/" + std::to_string(cuts.size());
    for (std::size_t i = 0; i < cuts.size() && !stopping_; ++i) {
      co_await sleep_until(timer, origin_ + cuts[i].start);
      if (stopping_) break;
      in_cut_ = true;
      if (options_.cut_mode == EmulatorOptions::CutMode::close) {
        drop_connections(DiscardReason::cut);  // before the line: tests see the effect after it
        print_line("link-emulator: cut " + std::to_string(i + 1) + of + " begins");
      } else {
        poke();  // the loops stop moving bytes
        print_line("link-emulator: cut " + std::to_string(i + 1) + of + " begins (silent)");
      }
      co_await sleep_until(timer, origin_ + cuts[i].end());
      if (stopping_) break;
      in_cut_ = false;
      print_line("link-emulator: cut " + std::to_string(i + 1) + of + " ends");
      poke();
    }
  }

  asio::awaitable<void> stats_loop() {
    asio::steady_timer& timer = new_waiter();
    TimePoint next = origin_;
    while (!stopping_) {
      next += options_.stats_interval;
      co_await sleep_until(timer, next);
      if (stopping_) break;
      print_line(format_stats("stats", a_to_b_.counters(), b_to_a_.counters()));
    }
  }

  asio::io_context& io_;
  const EmulatorOptions& options_;
  Side a_;
  Side b_;
  Impairment a_to_b_;
  Impairment b_to_a_;
  std::list<asio::steady_timer> waiters_;  // a list: loops keep references to their timer
  TimePoint origin_{};
  bool in_cut_ = false;
  bool stopping_ = false;
};

}  // namespace

int run_link_emulator(const EmulatorOptions& options) {
  asio::io_context io(1);
  // Before the ready line, so that a signal sent right after it is not lost.
  asio::signal_set signals(io, SIGINT, SIGTERM);
  Shell shell(io, options);
  signals.async_wait([&](const boost::system::error_code& ec, int) {
    if (!ec) shell.stop();
  });
  shell.start();
  io.run();
  return 0;
}

}  // namespace canbridge::emulator
