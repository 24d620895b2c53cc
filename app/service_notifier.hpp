// Tells the service manager how a role is doing, in sd_notify(3)'s protocol without libsystemd:
// readiness, a status line, stopping, and watchdog keep-alives sent from the role's own loop, so
// a stalled loop stops them and systemd restarts the process.
#pragma once

#include <sys/types.h>

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <optional>
#include <string>
#include <string_view>

namespace canbridge::bridge {

// What the service manager put in the environment (systemd.exec(5)).
struct NotifyEnvironment {
  // $NOTIFY_SOCKET: a filesystem path, or "@name" for an abstract socket; "" when not a service.
  std::string socket;
  // $WATCHDOG_USEC: the watchdog timeout; zero when no watchdog is asked for.
  std::chrono::microseconds watchdog_timeout{0};
  // $WATCHDOG_PID: the process the watchdog is for; the keep-alives are sent only from it.
  std::optional<pid_t> watchdog_pid;

  static NotifyEnvironment from_process();
};

class ServiceNotifier {
 public:
  // Does nothing at all (no socket, no timer) when env.socket is empty.
  ServiceNotifier(boost::asio::any_io_executor executor,
                  NotifyEnvironment env = NotifyEnvironment::from_process());
  ~ServiceNotifier();
  ServiceNotifier(const ServiceNotifier&) = delete;
  ServiceNotifier& operator=(const ServiceNotifier&) = delete;

  // READY=1 with a STATUS= line; starts the watchdog keep-alives when one is asked for.
  void ready(std::string_view status);
  void status(std::string_view text);
  // STOPPING=1 (systemd then no longer expects keep-alives); stops the watchdog.
  void stopping();

  // How often WATCHDOG=1 goes out (half the timeout, as sd_watchdog_enabled(3) advises); zero
  // when there is no watchdog for this process.
  std::chrono::microseconds watchdog_period() const { return watchdog_period_; }
  bool enabled() const { return fd_ >= 0; }

 private:
  void send(std::string_view message);
  void arm_watchdog();

  std::string socket_;
  std::chrono::microseconds watchdog_period_{0};
  int fd_ = -1;
  bool send_failure_logged_ = false;
  bool petting_ = false;  // between ready() and stopping()
  boost::asio::steady_timer watchdog_;
};

}  // namespace canbridge::bridge
