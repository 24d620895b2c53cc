// Keeps one serial backbone line open: opens and configures the tty, hands each new StreamLink to
// the user, and reopens with backoff whenever the link ends (dead line, device gone, error).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "backbone/reconnect_backoff.hpp"
#include "backbone/stream_link.hpp"

namespace canbridge::backbone {

struct SerialOptions {
  std::string device;  // e.g. /dev/ttyS0, /dev/ttyUSB0, or a pty's path
  unsigned baud = 115200;
  // 8N1 always; hardware (RTS/CTS) flow control only when the cable carries it.
  bool hardware_flow_control = false;
  // Between opens: backoff_min, doubling after failed opens and refused links up to backoff_max.
  std::chrono::milliseconds backoff_min{100};
  std::chrono::milliseconds backoff_max{5000};
  StreamLinkOptions link;
};

struct SerialCounters {
  std::uint64_t opens = 0;
  std::uint64_t open_failures = 0;
};

// Opens `device` and applies raw mode, baud, 8N1 and flow control; throws nothing.
std::error_code open_serial_port(boost::asio::serial_port& port, const SerialOptions& options);

// Not thread-safe: call every member on the executor's thread.
class SerialClient : public std::enable_shared_from_this<SerialClient> {
 public:
  // Called with every new link; the handler must call link->start(...).
  using ConnectedHandler = std::function<void(std::shared_ptr<StreamLink> link)>;

  static std::shared_ptr<SerialClient> create(boost::asio::any_io_executor executor,
                                              SerialOptions options);
  ~SerialClient();
  SerialClient(const SerialClient&) = delete;
  SerialClient& operator=(const SerialClient&) = delete;

  void start(ConnectedHandler on_connected);  // call once
  void stop();                                // closes the current link; idempotent

  SerialCounters counters() const { return counters_; }
  std::shared_ptr<StreamLink> link() const { return link_; }

 private:
  SerialClient(boost::asio::any_io_executor executor, SerialOptions options);
  boost::asio::awaitable<void> run();

  boost::asio::any_io_executor executor_;
  SerialOptions options_;
  boost::asio::steady_timer backoff_timer_;
  ReconnectBackoff backoff_;
  ConnectedHandler on_connected_;
  std::shared_ptr<StreamLink> link_;
  SerialCounters counters_;
  bool started_ = false;
  bool stopped_ = false;
  bool failing_ = false;
};

}  // namespace canbridge::backbone
