#include "tests/system_remote/endpoint_client.hpp"

#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <system_error>

namespace canbridge::test {

EndpointClient::EndpointClient(const std::string& path) {
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  if (path.size() >= sizeof address.sun_path) {
    throw std::system_error(ENAMETOOLONG, std::generic_category(), path);
  }
  std::memcpy(address.sun_path, path.c_str(), path.size() + 1);
  fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd_ < 0) throw std::system_error(errno, std::generic_category(), "socket");
  if (::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) {
    const int e = errno;
    ::close(fd_);
    throw std::system_error(e, std::generic_category(), "connect " + path);
  }
}

EndpointClient::~EndpointClient() {
  if (fd_ >= 0) ::close(fd_);
}

void EndpointClient::send(std::string_view bytes) {
  while (!bytes.empty()) {
    const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw std::system_error(errno, std::generic_category(), "send");
    }
    bytes.remove_prefix(static_cast<std::size_t>(n));
  }
}

void EndpointClient::send_byte_by_byte(std::string_view bytes) {
  for (const char c : bytes) send(std::string_view(&c, 1));
}

void EndpointClient::shutdown_send() {
  ::shutdown(fd_, SHUT_WR);
}

std::optional<std::string> EndpointClient::line(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    if (const auto lf = buffer_.find('\n'); lf != std::string::npos) {
      std::string text = buffer_.substr(0, lf);
      buffer_.erase(0, lf + 1);
      if (!text.empty() && text.back() == '\r') {
        text.pop_back();
      } else {
        ++bare_lf_;
      }
      return text;
    }
    if (closed_) return std::nullopt;
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return std::nullopt;
    pollfd p{fd_, POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(left.count()));
    if (ready < 0 && errno == EINTR) continue;
    if (ready <= 0) return std::nullopt;
    char chunk[4096];
    const ssize_t n = ::recv(fd_, chunk, sizeof chunk, 0);
    if (n < 0 && (errno == EINTR || errno == EAGAIN)) continue;
    if (n <= 0) {
      closed_ = true;
      continue;
    }
    buffer_.append(chunk, static_cast<std::size_t>(n));
  }
}

std::vector<std::string> EndpointClient::lines_until(std::string_view last,
                                                     std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::vector<std::string> lines;
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    auto next = line(std::max(left, std::chrono::milliseconds(0)));
    if (!next) return lines;
    lines.push_back(std::move(*next));
    if (lines.back().starts_with(last)) return lines;
  }
}

std::string EndpointClient::ask(const std::string& request, std::chrono::milliseconds timeout) {
  send(request + "\n");
  return line(timeout).value_or("");
}

}  // namespace canbridge::test
