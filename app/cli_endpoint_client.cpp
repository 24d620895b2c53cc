#include "app/cli_endpoint_client.hpp"

#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace canbridge::cli {

namespace {

std::error_code last_error() {
  return {errno, std::generic_category()};
}

int connect_unix(const std::string& path, std::error_code& ec) {
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  if (path.size() >= sizeof addr.sun_path) {
    ec = std::make_error_code(std::errc::filename_too_long);
    return -1;
  }
  std::memcpy(addr.sun_path, path.data(), path.size());
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    ec = last_error();
    return -1;
  }
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    ec = last_error();
    ::close(fd);
    return -1;
  }
  return fd;
}

int connect_tcp(const std::string& host, const std::string& port, std::error_code& ec) {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  if (::getaddrinfo(host.c_str(), port.c_str(), &hints, &found) != 0 || found == nullptr) {
    ec = std::make_error_code(std::errc::host_unreachable);
    return -1;
  }
  int fd = -1;
  ec = std::make_error_code(std::errc::connection_refused);
  for (addrinfo* a = found; a != nullptr; a = a->ai_next) {
    fd = ::socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
      ec.clear();
      break;
    }
    ec = last_error();
    ::close(fd);
    fd = -1;
  }
  ::freeaddrinfo(found);
  return fd;
}

}  // namespace

EndpointAddress parse_endpoint(std::string_view text) {
  EndpointAddress a;
  const std::size_t colon = text.rfind(':');
  const bool digits_after = colon != std::string_view::npos && colon + 1 < text.size() &&
                            std::all_of(text.begin() + static_cast<std::ptrdiff_t>(colon) + 1,
                                        text.end(), [](char c) { return c >= '0' && c <= '9'; });
  if (digits_after && colon > 0 && text.find('/') == std::string_view::npos) {
    a.tcp = true;
    std::string_view host = text.substr(0, colon);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {  // [::1]:5000
      host = host.substr(1, host.size() - 2);
    }
    a.host = std::string(host);
    a.port = std::string(text.substr(colon + 1));
  } else {
    a.path = std::string(text);
  }
  return a;
}

std::unique_ptr<EndpointConnection> EndpointConnection::open(const EndpointAddress& address,
                                                             std::error_code& ec) {
  ec.clear();
  const int fd =
      address.tcp ? connect_tcp(address.host, address.port, ec) : connect_unix(address.path, ec);
  if (fd < 0) return nullptr;
  return std::unique_ptr<EndpointConnection>(new EndpointConnection(fd));
}

EndpointConnection::~EndpointConnection() {
  if (fd_ >= 0) ::close(fd_);
}

std::error_code EndpointConnection::send_line(std::string_view line) {
  std::string out(line);
  out += '\n';
  std::size_t sent = 0;
  while (sent < out.size()) {
    const ssize_t n = ::send(fd_, out.data() + sent, out.size() - sent, MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      return last_error();
    }
    sent += static_cast<std::size_t>(n);
  }
  return {};
}

std::error_code EndpointConnection::read_line(std::string& line,
                                              std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    const std::size_t end = buffer_.find('\n');
    if (end != std::string::npos) {
      std::size_t len = end;
      if (len > 0 && buffer_[len - 1] == '\r') --len;
      line.assign(buffer_, 0, len);
      buffer_.erase(0, end + 1);
      return {};
    }
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return std::make_error_code(std::errc::timed_out);
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(std::min<long long>(left.count(), 1 << 30)));
    if (ready < 0) {
      if (errno == EINTR) return std::make_error_code(std::errc::interrupted);
      return last_error();
    }
    if (ready == 0) continue;  // the deadline check above ends the wait
    char chunk[65536];
    const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
    if (n < 0) {
      if (errno == EINTR) return std::make_error_code(std::errc::interrupted);
      return last_error();
    }
    if (n == 0) return std::make_error_code(std::errc::connection_reset);
    buffer_.append(chunk, static_cast<std::size_t>(n));
  }
}

}  // namespace canbridge::cli
