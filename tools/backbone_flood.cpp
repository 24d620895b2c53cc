// canbridge-backbone-flood: hostile peers against a surface's backbone port, for the admission
// tests and for operators checking a deployment: idle connections that never say anything, or
// failing handshakes (garbage, a TLS ClientHello-like record, a session hello with an unknown
// name, or a real TLS 1.3 PSK handshake with a key the server does not know). Reports what the
// server did with them.
//
//   canbridge-backbone-flood --connect 127.0.0.1:7000 --idle 1100 [--duration 10] [--rate 500]
//   canbridge-backbone-flood --connect 127.0.0.1:7000 --bad-handshakes 1100 [--concurrency 1]
//       [--kind mixed|bytes|garbage|tls|hello|psk] [--linger-ms 500] [--cycle --duration 10]
//       [--psk-name NAME]
//   either with [--bind ADDRESS]: connect from this local address (e.g. 127.0.0.2, any of
//   127/8 on Linux), so the flood comes from another source than a real peer on the same host;
//   with [--sources N] the connections take turns among the N addresses from --bind on
//   (127.0.2.1 ... 127.0.2.N), a flood from many hosts that a per-source throttle cannot stop
//
// --kind psk runs a real TLS 1.3 handshake (OpenSSL, as a gateway does) offering a fresh random
// key: every even one under --psk-name (a configured gateway's name: a wrong key), every odd one
// under an unknown name, so each costs the server a real handshake attempt. The final line then
// also counts tls_refused (the server ended the handshake) and tls_accepted (it must stay 0).
//
// Prints "backbone-flood: holding N" once N idle connections are open at the same time (or
// "backbone-flood: started" for handshakes), a progress line every --report-ms, and a final line
// "backbone-flood: done ..." with the counts and the elapsed time. Ends after --duration seconds
// (idle) or once every handshake ran, or at SIGINT/SIGTERM.
#include <netinet/in.h>
#include <sys/socket.h>

#include <array>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/connect.hpp>
#include <boost/asio/experimental/awaitable_operators.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <boost/asio/write.hpp>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/tls_upgrade.hpp"
#include "coro/no_error.hpp"
#include "coro/spawn_owned.hpp"
#include "session.pb.h"

namespace {

namespace asio = boost::asio;
using asio::ip::tcp;
using Clock = std::chrono::steady_clock;
using canbridge::coro::kNoError;
using namespace asio::experimental::awaitable_operators;

struct Options {
  std::string host = "127.0.0.1";
  std::string port;
  std::string bind;         // local address to connect from; empty: the kernel picks
  std::size_t sources = 1;  // with bind: that many consecutive IPv4 addresses, in turn
  std::size_t idle = 0;
  std::size_t bad_handshakes = 0;
  std::size_t concurrency = 0;  // 0: idle: all at once; handshakes: 1 (one after another)
  double rate = 0;              // connects per second, 0: as fast as possible
  double duration_s = 10;       // idle only
  bool reopen = true;           // idle: open a new connection for each one the server closed
  bool cycle = false;           // handshakes: start over after N until --duration
  std::string kind = "mixed";
  std::string psk_name = "gateway";  // psk: the configured gateway name offered with a wrong key
  std::chrono::milliseconds linger{500};
  std::chrono::milliseconds report{1000};
};

struct Counts {
  std::uint64_t connected = 0;
  std::uint64_t connect_failed = 0;
  std::uint64_t closed_by_server = 0;  // EOF or reset from the server
  std::uint64_t closed_by_us = 0;      // handshakes the server left open past --linger-ms
  std::uint64_t sent_bytes = 0;
  std::uint64_t write_failed = 0;
  std::uint64_t held = 0;
  std::uint64_t held_peak = 0;
  std::uint64_t handshakes_done = 0;
  std::uint64_t tls_refused = 0;   // psk: the server failed the handshake
  std::uint64_t tls_accepted = 0;  // psk: the server completed it (a wrong key must never)
};

void usage() {
  std::cerr
      << "usage: canbridge-backbone-flood --connect HOST:PORT (--idle N | --bad-handshakes N)\n"
         "  [--concurrency C] [--rate CONNECTS_PER_S] [--duration S] [--no-reopen]\n"
         "  [--kind mixed|bytes|garbage|tls|hello|psk] [--linger-ms MS] [--report-ms MS] "
         "[--cycle]\n"
         "  [--psk-name NAME] [--bind LOCAL_ADDRESS [--sources N]]\n";
}

bool parse(int argc, char** argv, Options& o) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(arg + " needs a value");
      return argv[++i];
    };
    if (arg == "--connect") {
      const std::string v = value();
      const auto colon = v.rfind(':');
      if (colon == std::string::npos) throw std::invalid_argument("--connect wants HOST:PORT");
      o.host = v.substr(0, colon);
      o.port = v.substr(colon + 1);
    } else if (arg == "--bind") {
      o.bind = value();
    } else if (arg == "--sources") {
      o.sources = std::stoul(value());
    } else if (arg == "--idle") {
      o.idle = std::stoul(value());
    } else if (arg == "--bad-handshakes") {
      o.bad_handshakes = std::stoul(value());
    } else if (arg == "--concurrency") {
      o.concurrency = std::stoul(value());
    } else if (arg == "--rate") {
      o.rate = std::stod(value());
    } else if (arg == "--duration") {
      o.duration_s = std::stod(value());
    } else if (arg == "--cycle") {
      o.cycle = true;
    } else if (arg == "--no-reopen") {
      o.reopen = false;
    } else if (arg == "--kind") {
      o.kind = value();
    } else if (arg == "--psk-name") {
      o.psk_name = value();
    } else if (arg == "--linger-ms") {
      o.linger = std::chrono::milliseconds(std::stol(value()));
    } else if (arg == "--report-ms") {
      o.report = std::chrono::milliseconds(std::stol(value()));
    } else {
      throw std::invalid_argument("unknown option " + arg);
    }
  }
  if (o.port.empty() || (o.idle == 0) == (o.bad_handshakes == 0)) return false;
  if (o.sources == 0 || o.sources > 65536 || (o.sources > 1 && o.bind.empty())) {
    throw std::invalid_argument("--sources wants 1..65536 and a --bind address to start from");
  }
  if (o.kind != "mixed" && o.kind != "bytes" && o.kind != "garbage" && o.kind != "tls" &&
      o.kind != "hello" && o.kind != "psk") {
    throw std::invalid_argument(
        "--kind: mixed, bytes (garbage and tls), garbage, tls, hello or psk");
  }
  return true;
}

// What a failing handshake says first. `n` varies the content and, for "mixed", the kind.
std::string bad_handshake(const std::string& kind, std::uint64_t n) {
  static const char* kKinds[] = {"garbage", "tls", "hello"};
  const std::string k = kind == "mixed" ? kKinds[n % 3] : kind == "bytes" ? kKinds[n % 2] : kind;
  std::string out;
  if (k == "garbage") {
    // A length prefix far beyond any message size, then noise.
    out = "\xff\xff\xff\xff\x0f";
    for (int i = 0; i < 64; ++i) out.push_back(static_cast<char>((n * 131 + i * 7) & 0xff));
  } else if (k == "tls") {
    // A TLS 1.2-framed handshake record carrying a truncated ClientHello (as a TLS 1.3 client
    // opens), which neither a plain session nor a TLS server can complete.
    const unsigned char record[] = {0x16, 0x03, 0x01, 0x00, 0x2f, 0x01,
                                    0x00, 0x00, 0x2b, 0x03, 0x03};
    out.assign(reinterpret_cast<const char*>(record), sizeof record);
    for (int i = 0; i < 32; ++i) out.push_back(static_cast<char>((n + i) & 0xff));
  } else {
    canbridge::v1::Envelope envelope;
    auto* hello = envelope.mutable_hello();
    hello->set_protocol_major(1);
    hello->set_role(canbridge::v1::Hello::ROLE_GATEWAY);
    hello->set_name("flood-" + std::to_string(n));
    hello->set_session_id(0x5eed0000ull + n);
    const std::string body = envelope.SerializeAsString();
    canbridge::backbone::append_delimited(
        out, {reinterpret_cast<const std::uint8_t*>(body.data()), body.size()});
  }
  return out;
}

// A gateway's TLS PSK client offering a fresh random key under `name`: no server knows the key.
std::shared_ptr<canbridge::backbone::TlsUpgrade> stranger_psk(const std::string& name) {
  std::random_device random;
  std::array<std::uint8_t, canbridge::backbone::kPreSharedKeySize> bytes{};
  for (auto& b : bytes) b = static_cast<std::uint8_t>(random() & 0xffu);
  return canbridge::backbone::TlsUpgrade::create(canbridge::backbone::TlsGatewayPsk{
      name, {canbridge::backbone::PreSharedKey(bytes)}, "surface", nullptr});
}

class Flood {
 public:
  Flood(asio::io_context& io, Options options)
      : io_(io), options_(std::move(options)), pacer_next_(Clock::now()), report_timer_(io) {
    if (options_.kind == "psk") {
      psk_[0] = stranger_psk(options_.psk_name);
      psk_[1] = stranger_psk(options_.psk_name + "-stranger");
    }
  }

  int run() {
    start_ = Clock::now();
    tcp::resolver resolver(io_);
    boost::system::error_code ec;
    const auto results = resolver.resolve(options_.host, options_.port, ec);
    if (ec || results.empty()) {
      std::cerr << "backbone-flood: cannot resolve " << options_.host << ":" << options_.port
                << ": " << ec.message() << "\n";
      return 2;
    }
    endpoint_ = *results.begin();
    if (!options_.bind.empty()) {
      bind_address_ = asio::ip::make_address(options_.bind, ec);
      if (ec) {
        std::cerr << "backbone-flood: --bind " << options_.bind << ": " << ec.message() << "\n";
        return 2;
      }
      if (options_.sources > 1 && !bind_address_->is_v4()) {
        std::cerr << "backbone-flood: --sources needs an IPv4 --bind address\n";
        return 2;
      }
    }
    asio::signal_set signals(io_, SIGINT, SIGTERM);
    signals.async_wait([this](boost::system::error_code e, int) {
      if (!e) stop();
    });
    const bool idle = options_.idle > 0;
    const std::size_t workers =
        options_.concurrency > 0 ? options_.concurrency : (idle ? options_.idle : 1);
    if (idle || options_.cycle) {
      deadline_ = start_ + std::chrono::duration_cast<Clock::duration>(
                               std::chrono::duration<double>(options_.duration_s));
    } else {
      std::printf("backbone-flood: started\n");
      std::fflush(stdout);
    }
    const std::size_t count = idle ? options_.idle : std::min(workers, options_.bad_handshakes);
    for (std::size_t i = 0; i < count; ++i) {
      ++running_;
      canbridge::coro::spawn_owned(io_, idle ? idle_worker() : handshake_worker(),
                                   [this, &signals](const std::string& failure) {
                                     if (!failure.empty()) {
                                       std::cerr << "backbone-flood: " << failure << "\n";
                                     }
                                     if (--running_ == 0) {
                                       report_timer_.cancel();
                                       signals.cancel();
                                     }
                                   });
    }
    canbridge::coro::spawn_owned(io_, reporter(), [](const std::string&) {});
    io_.run();
    print("done");
    return 0;
  }

 private:
  bool stopping() const { return stopped_ || Clock::now() >= deadline_; }

  void stop() {
    stopped_ = true;
    for (tcp::socket* s : open_) {
      boost::system::error_code ignored;
      s->close(ignored);
    }
  }

  // Waits for this connect's turn under --rate.
  asio::awaitable<void> pace() {
    if (options_.rate <= 0) co_return;
    const auto now = Clock::now();
    if (pacer_next_ < now) pacer_next_ = now;
    const auto at = pacer_next_;
    pacer_next_ += std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(1.0 / options_.rate));
    asio::steady_timer timer(io_, at);
    co_await timer.async_wait(kNoError);
  }

  // Connects; the socket is registered so stop() can close it, connecting or open.
  asio::awaitable<bool> connect(tcp::socket& socket) {
    co_await pace();
    if (stopping()) co_return false;
    // Registered before connecting: when the server's accept queue is full the SYN waits for
    // minutes, and stop() must be able to end such a connect as well.
    open_.push_back(&socket);
    if (bind_address_) bind_local(socket);
    auto [ec] = co_await socket.async_connect(endpoint_, kNoError);
    if (ec) {
      std::erase(open_, &socket);
      if (!stopping()) ++counts_.connect_failed;
      co_return false;
    }
    ++counts_.connected;
    counts_.held_peak = std::max(counts_.held_peak, ++counts_.held);
    if (options_.idle > 0 && counts_.held == options_.idle && !announced_) {
      announced_ = true;
      print("holding");
    }
    co_return true;
  }

  // Binds the socket to --bind; the port is left to connect() (IP_BIND_ADDRESS_NO_PORT), which
  // picks it per destination, so thousands of short connections do not run out of ports.
  void bind_local(tcp::socket& socket) {
    boost::system::error_code ec;
    socket.open(endpoint_.protocol(), ec);
    if (!ec && bind_address_->is_v4()) {
      const int on = 1;
      ::setsockopt(socket.native_handle(), IPPROTO_IP, IP_BIND_ADDRESS_NO_PORT, &on, sizeof on);
    }
    asio::ip::address local = *bind_address_;
    if (options_.sources > 1) {  // the next source in turn
      const auto base = bind_address_->to_v4().to_uint();
      local = asio::ip::address_v4(
          static_cast<asio::ip::address_v4::uint_type>(base + next_source_++ % options_.sources));
    }
    if (!ec) socket.bind(tcp::endpoint(local, 0), ec);
    if (ec && !warned_bind_) {
      warned_bind_ = true;
      std::cerr << "backbone-flood: cannot bind to " << options_.bind << ": " << ec.message()
                << "\n";
    }
  }

  std::size_t next_source_ = 0;

  void forget(tcp::socket& socket) {
    std::erase(open_, &socket);
    --counts_.held;
    boost::system::error_code ignored;
    socket.close(ignored);
  }

  asio::awaitable<void> idle_worker() {
    do {
      tcp::socket socket(io_);
      if (!co_await connect(socket)) {
        if (stopping()) break;
        continue;
      }
      char byte = 0;
      // Nothing is ever sent: the read ends when the server closes the connection (or stop()).
      // An idle worker also ends its read at --duration: a timer closes every socket then.
      co_await socket.async_read_some(asio::buffer(&byte, 1), kNoError);
      if (!stopping()) ++counts_.closed_by_server;
      forget(socket);
    } while (options_.reopen && !stopping());
  }

  // Reads (a refusal, the server's hello) until the server closes the connection.
  static asio::awaitable<void> read_to_close(tcp::socket& socket) {
    std::vector<char> sink(4096);
    for (;;) {
      auto [ec, got] = co_await socket.async_read_some(asio::buffer(sink), kNoError);
      if (ec || got == 0) co_return;
    }
  }

  asio::awaitable<void> handshake_worker() {
    for (;;) {
      if (options_.cycle && next_handshake_ >= options_.bad_handshakes) next_handshake_ = 0;
      if (stopping() || next_handshake_ >= options_.bad_handshakes) break;
      const std::uint64_t n = next_handshake_++;
      tcp::socket socket(io_);
      if (!co_await connect(socket)) continue;
      if (psk_[0]) {
        co_await tls_handshake(socket, n);
        continue;
      }
      const std::string hello = bad_handshake(options_.kind, n);
      auto [write_error, written] =
          co_await asio::async_write(socket, asio::buffer(hello), kNoError);
      counts_.sent_bytes += written;
      if (write_error) ++counts_.write_failed;  // the server closed it first
      // Wait for the server to close it, at most --linger-ms.
      asio::steady_timer linger(io_, options_.linger);
      auto closed = co_await (read_to_close(socket) || linger.async_wait(kNoError));
      if (closed.index() == 0) {
        ++counts_.closed_by_server;
      } else {
        ++counts_.closed_by_us;
      }
      ++counts_.handshakes_done;
      forget(socket);
    }
  }

  // One real TLS 1.3 handshake with a key the server does not know, bounded by --linger-ms.
  asio::awaitable<void> tls_handshake(tcp::socket& socket, std::uint64_t n) {
    const auto upgrade = psk_[n % 2];
    tcp::socket handshaking = std::move(socket);
    forget(socket);  // the moved-from socket; the handshake owns the connection now
    asio::steady_timer linger(io_, options_.linger);
    auto outcome =
        co_await (upgrade->upgrade(std::move(handshaking), {}) || linger.async_wait(kNoError));
    ++counts_.handshakes_done;
    if (outcome.index() == 1) {
      ++counts_.closed_by_us;  // the server neither finished nor refused it in time
      co_return;
    }
    auto& result = std::get<0>(outcome);
    if (result.link) {
      ++counts_.tls_accepted;
      result.link->close(std::make_error_code(std::errc::connection_aborted));
    } else {
      ++counts_.tls_refused;
      ++counts_.closed_by_server;
    }
  }

  asio::awaitable<void> reporter() {
    while (running_ > 0) {
      report_timer_.expires_after(options_.report);
      co_await report_timer_.async_wait(kNoError);
      if (running_ == 0) break;
      if (Clock::now() >= deadline_ && !stopped_) stop();
      print("progress");
    }
  }

  void print(const char* what) {
    const double elapsed = std::chrono::duration<double>(Clock::now() - start_).count();
    std::printf(
        "backbone-flood: %s %s connected=%llu connect_failed=%llu closed_by_server=%llu "
        "closed_by_us=%llu write_failed=%llu held=%llu held_peak=%llu handshakes=%llu "
        "tls_refused=%llu tls_accepted=%llu elapsed_s=%.3f\n",
        what, options_.idle > 0 ? "idle" : "handshakes",
        static_cast<unsigned long long>(counts_.connected),
        static_cast<unsigned long long>(counts_.connect_failed),
        static_cast<unsigned long long>(counts_.closed_by_server),
        static_cast<unsigned long long>(counts_.closed_by_us),
        static_cast<unsigned long long>(counts_.write_failed),
        static_cast<unsigned long long>(counts_.held),
        static_cast<unsigned long long>(counts_.held_peak),
        static_cast<unsigned long long>(counts_.handshakes_done),
        static_cast<unsigned long long>(counts_.tls_refused),
        static_cast<unsigned long long>(counts_.tls_accepted), elapsed);
    std::fflush(stdout);
  }

  asio::io_context& io_;
  Options options_;
  tcp::endpoint endpoint_;
  Clock::time_point start_;
  Clock::time_point deadline_ = Clock::time_point::max();
  Clock::time_point pacer_next_;
  asio::steady_timer report_timer_;
  std::vector<tcp::socket*> open_;
  Counts counts_;
  std::size_t running_ = 0;
  std::uint64_t next_handshake_ = 0;
  bool stopped_ = false;
  bool announced_ = false;
  bool warned_bind_ = false;
  std::optional<asio::ip::address> bind_address_;
  std::array<std::shared_ptr<canbridge::backbone::TlsUpgrade>, 2> psk_;  // psk: wrong key, stranger
};

}  // namespace

int main(int argc, char** argv) {
  Options options;
  try {
    if (!parse(argc, argv, options)) {
      usage();
      return 2;
    }
  } catch (const std::exception& e) {
    std::cerr << "backbone-flood: " << e.what() << "\n";
    usage();
    return 2;
  }
  asio::io_context io(1);
  return Flood(io, std::move(options)).run();
}
