#include "app/service_notifier.hpp"

#include <spdlog/spdlog.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstddef>
#include <cstdlib>
#include <cstring>

namespace canbridge::bridge {

namespace {

// A decimal number from the environment, nullopt when absent or malformed.
template <typename Number>
std::optional<Number> number_from_env(const char* name) {
  const char* text = std::getenv(name);
  if (text == nullptr || *text == '\0') return std::nullopt;
  Number value{};
  const char* end = text + std::strlen(text);
  const auto [at, ec] = std::from_chars(text, end, value);
  if (ec != std::errc{} || at != end) return std::nullopt;
  return value;
}

}  // namespace

NotifyEnvironment NotifyEnvironment::from_process() {
  NotifyEnvironment env;
  if (const char* socket = std::getenv("NOTIFY_SOCKET")) env.socket = socket;
  if (auto usec = number_from_env<std::uint64_t>("WATCHDOG_USEC")) {
    env.watchdog_timeout = std::chrono::microseconds(*usec);
  }
  env.watchdog_pid = number_from_env<pid_t>("WATCHDOG_PID");
  return env;
}

ServiceNotifier::ServiceNotifier(boost::asio::any_io_executor executor, NotifyEnvironment env)
    : socket_(std::move(env.socket)), watchdog_(std::move(executor)) {
  if (socket_.empty()) return;
  // A path or an abstract name only; sd_notify's vsock: addresses are for VMs, not for us.
  const bool abstract = socket_.front() == '@';
  if ((!abstract && socket_.front() != '/') || socket_.size() >= sizeof(sockaddr_un::sun_path)) {
    spdlog::warn("NOTIFY_SOCKET={}: not a Unix socket path or @name; not notifying systemd",
                 socket_);
    return;
  }
  fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
  if (fd_ < 0) {
    spdlog::warn("NOTIFY_SOCKET={}: socket: {}; not notifying systemd", socket_,
                 std::strerror(errno));
    return;
  }
  // A watchdog meant for another process (a parent that exec'd us) is not ours to pet.
  const bool ours = !env.watchdog_pid || *env.watchdog_pid == ::getpid();
  if (ours && env.watchdog_timeout.count() > 0) watchdog_period_ = env.watchdog_timeout / 2;
}

ServiceNotifier::~ServiceNotifier() {
  if (fd_ >= 0) ::close(fd_);
}

void ServiceNotifier::ready(std::string_view status) {
  send("READY=1\nSTATUS=" + std::string(status));
  if (watchdog_period_.count() > 0 && !petting_) {
    petting_ = true;
    arm_watchdog();
  }
}

void ServiceNotifier::status(std::string_view text) {
  send("STATUS=" + std::string(text));
}

void ServiceNotifier::stopping() {
  // The flag, not just cancel(): a keep-alive already due (its handler queued) would otherwise
  // still go out after STOPPING=1 and arm the next one, keeping the draining loop busy.
  petting_ = false;
  watchdog_.cancel();
  send("STOPPING=1\nSTATUS=stopping");
}

void ServiceNotifier::arm_watchdog() {
  // From a timer on the role's loop: if the loop stalls, the keep-alives stop.
  watchdog_.expires_after(watchdog_period_);
  watchdog_.async_wait([this](boost::system::error_code ec) {
    if (ec || !petting_) return;
    send("WATCHDOG=1");
    arm_watchdog();
  });
}

void ServiceNotifier::send(std::string_view message) {
  if (fd_ < 0) return;
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::memcpy(address.sun_path, socket_.data(), socket_.size());
  if (socket_.front() == '@') address.sun_path[0] = '\0';  // abstract: no terminating NUL
  const auto length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + socket_.size());
  const ssize_t sent = ::sendto(fd_, message.data(), message.size(), MSG_NOSIGNAL | MSG_DONTWAIT,
                                reinterpret_cast<const sockaddr*>(&address), length);
  // Never fatal: the role works without its manager hearing of it. Logged once, not per pet.
  if (sent < 0 && !send_failure_logged_) {
    send_failure_logged_ = true;
    spdlog::warn("NOTIFY_SOCKET={}: cannot notify systemd: {}", socket_, std::strerror(errno));
  }
}

}  // namespace canbridge::bridge
