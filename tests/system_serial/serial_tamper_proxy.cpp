// serial-tamper-proxy: an attacker on a serial backbone line, for rig tests. Two ptys (like
// canbridge-link-emulator's "pty:PATH"): bytes from b go to a unchanged; the frames from a to b
// are deframed (COBS + CRC-32C, backbone/serial_framing) and re-framed, and on a command read
// from a FIFO the next frame of at least --min-bytes payload bytes is attacked:
//   tamper    one byte in the middle of its payload flipped, the CRC recomputed (so the frame
//             passes the line's check and only the session's MAC can tell);
//   truncate  cut to its first 10 bytes (shorter than a seal's counter and tag), valid CRC;
//   replay    sent, then the frame of a (at least --min-bytes) before it sent again unchanged.
// Prints "serial-tamper-proxy: ready" once the ptys exist and one line per attack done.
//
// Usage: serial-tamper-proxy --a PATH --b PATH --commands FIFO [--min-bytes N]
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <boost/asio/io_context.hpp>
#include <boost/asio/posix/stream_descriptor.hpp>
#include <boost/asio/read_until.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/streambuf.hpp>
#include <boost/asio/write.hpp>
#include <cstdio>
#include <deque>
#include <istream>
#include <string>
#include <vector>

#include "backbone/serial_framing.hpp"
#include "tools/link_emulator/pty_endpoint.hpp"

namespace {

namespace asio = boost::asio;
using canbridge::backbone::append_serial_frame;
using canbridge::backbone::SerialDeframer;
using canbridge::emulator::PtyEndpoint;
using Bytes = std::vector<std::uint8_t>;

constexpr std::size_t kTruncatedSize = 10;
constexpr std::size_t kHistory = 16;

class Proxy {
 public:
  Proxy(asio::io_context& io, const std::string& a, const std::string& b, int commands,
        std::size_t min_bytes)
      : a_(io, a), b_(io, b), commands_(io, commands), min_bytes_(min_bytes), deframer_(1 << 20) {}

  void start() {
    read_a();
    read_b();
    read_command();
    std::printf("serial-tamper-proxy: ready a=%s b=%s\n", a_.link_path().c_str(),
                b_.link_path().c_str());
    std::fflush(stdout);
  }

 private:
  void read_a() {
    a_.master().async_read_some(asio::buffer(from_a_), [this](auto ec, std::size_t n) {
      if (ec) return;  // PtyEndpoint holds the slave open: only at shutdown
      std::string out;
      deframer_.feed({from_a_.data(), n}, [&](std::span<const std::uint8_t> payload) {
        forward(Bytes(payload.begin(), payload.end()), out);
      });
      if (!out.empty()) asio::write(b_.master(), asio::buffer(out), ignored_);
      read_a();
    });
  }

  void read_b() {
    b_.master().async_read_some(asio::buffer(from_b_), [this](auto ec, std::size_t n) {
      if (ec) return;
      asio::write(a_.master(), asio::buffer(from_b_.data(), n), ignored_);
      read_b();
    });
  }

  void forward(Bytes payload, std::string& out) {
    const bool target = payload.size() >= min_bytes_;
    if (target) remember(payload);  // as the sender wrote it
    if (target && !pending_.empty()) {
      const std::string action = pending_.front();
      pending_.pop_front();
      if (action == "tamper") {
        payload[payload.size() / 2] ^= 0x01;
        report("tampered", payload.size());
      } else if (action == "truncate") {
        report("truncated", payload.size());
        payload.resize(kTruncatedSize);
      } else if (action == "replay" && !history_.empty()) {
        append_serial_frame(out, payload);
        // The one before: a sealed message the receiver has opened already. (The oldest kept
        // could be the gateway's unsealed challenge, which only makes the surface start over.)
        payload = history_[history_.size() >= 2 ? history_.size() - 2 : 0];
        report("replayed", payload.size());
        append_serial_frame(out, payload);
        return;
      }
    }
    append_serial_frame(out, payload);
  }

  void remember(const Bytes& payload) {
    history_.push_back(payload);
    if (history_.size() > kHistory) history_.pop_front();
  }

  void report(const char* what, std::size_t size) {
    std::printf("serial-tamper-proxy: %s a frame of %zu payload bytes (attack %d)\n", what, size,
                ++attacks_);
    std::fflush(stdout);
  }

  void read_command() {
    asio::async_read_until(commands_, command_buffer_, '\n', [this](auto ec, std::size_t) {
      if (ec) return;
      std::istream in(&command_buffer_);
      std::string line;
      std::getline(in, line);
      if (line == "tamper" || line == "truncate" || line == "replay") {
        pending_.push_back(line);
      } else if (!line.empty()) {
        std::fprintf(stderr, "serial-tamper-proxy: unknown command '%s'\n", line.c_str());
      }
      read_command();
    });
  }

  PtyEndpoint a_;
  PtyEndpoint b_;
  asio::posix::stream_descriptor commands_;
  asio::streambuf command_buffer_;
  std::size_t min_bytes_;
  SerialDeframer deframer_;
  std::array<std::uint8_t, 4096> from_a_{};
  std::array<std::uint8_t, 4096> from_b_{};
  std::deque<std::string> pending_;
  std::deque<Bytes> history_;
  boost::system::error_code ignored_;
  int attacks_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::string a, b, commands;
  std::size_t min_bytes = 40;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--a") a = argv[i + 1];
    if (key == "--b") b = argv[i + 1];
    if (key == "--commands") commands = argv[i + 1];
    if (key == "--min-bytes") min_bytes = std::stoul(argv[i + 1]);
  }
  if (a.empty() || b.empty() || commands.empty()) {
    std::fprintf(stderr,
                 "usage: serial-tamper-proxy --a PATH --b PATH --commands FIFO [--min-bytes N]\n");
    return 2;
  }
  ::unlink(commands.c_str());
  if (::mkfifo(commands.c_str(), 0600) != 0) {
    std::perror("mkfifo");
    return 1;
  }
  // Read-write: the FIFO never reports end of file when a writer closes it.
  const int fd = ::open(commands.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    std::perror("open commands");
    return 1;
  }
  try {
    asio::io_context io(1);
    Proxy proxy(io, a, b, fd, min_bytes);
    asio::signal_set stop(io, SIGINT, SIGTERM);
    stop.async_wait([&io](auto, int) { io.stop(); });
    proxy.start();
    io.run();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "serial-tamper-proxy: %s\n", e.what());
    return 1;
  }
  ::unlink(commands.c_str());
  return 0;
}
