#include "tests/cli/fake_endpoint.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace canbridge::test {

namespace {

constexpr int kWaitMs = 10'000;  // a stuck client fails the test instead of hanging it

bool readable(int fd) {
  pollfd p{fd, POLLIN, 0};
  return ::poll(&p, 1, kWaitMs) == 1;
}

}  // namespace

FakeEndpoint::FakeEndpoint(std::vector<EndpointStep> script, Transport transport, bool close_at_end)
    : script_(std::move(script)), close_at_end_(close_at_end) {
  if (transport == Transport::unix_socket) {
    char templ[] = "/tmp/canbridge-cli-XXXXXX";
    if (::mkdtemp(templ) == nullptr) throw std::runtime_error("mkdtemp failed");
    dir_ = templ;
    address_ = dir_ + "/endpoint.sock";
    listen_fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, address_.c_str(), sizeof addr.sun_path - 1);
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
      throw std::runtime_error("bind " + address_ + " failed");
    }
  } else {
    listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t len = sizeof addr;
    if (::bind(listen_fd_, reinterpret_cast<sockaddr*>(&addr), len) != 0 ||
        ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&addr), &len) != 0) {
      throw std::runtime_error("bind 127.0.0.1:0 failed");
    }
    address_ = "127.0.0.1:" + std::to_string(ntohs(addr.sin_port));
  }
  if (::listen(listen_fd_, 4) != 0) throw std::runtime_error("listen failed");
  thread_ = std::thread([this] { serve(); });
}

FakeEndpoint::~FakeEndpoint() {
  if (thread_.joinable()) thread_.join();
  ::close(listen_fd_);
  if (!dir_.empty()) std::filesystem::remove_all(dir_);
}

std::vector<std::string> FakeEndpoint::received() {
  if (thread_.joinable()) thread_.join();
  return received_;
}

void FakeEndpoint::serve() {
  if (!readable(listen_fd_)) return;
  const int fd = ::accept(listen_fd_, nullptr, nullptr);
  if (fd < 0) return;
  std::string buffer;
  // The next line of the client; false when it closed or fell silent.
  const auto next_line = [&](std::string& line) {
    for (;;) {
      const std::size_t end = buffer.find('\n');
      if (end != std::string::npos) {
        line = buffer.substr(0, end);
        buffer.erase(0, end + 1);
        return true;
      }
      if (!readable(fd)) return false;
      char chunk[4096];
      const ssize_t n = ::recv(fd, chunk, sizeof chunk, 0);
      if (n <= 0) return false;
      buffer.append(chunk, static_cast<std::size_t>(n));
    }
  };
  std::string line;
  for (const auto& step : script_) {
    if (!next_line(line)) break;
    received_.push_back(line);
    if (line != step.expect) break;  // the test compares received() with the script
    std::string out;
    for (const auto& reply : step.replies) out += reply + "\r\n";
    if (!out.empty()) ::send(fd, out.data(), out.size(), MSG_NOSIGNAL);
  }
  if (!close_at_end_) {
    while (next_line(line)) received_.push_back(line);
  }
  ::close(fd);
}

}  // namespace canbridge::test
