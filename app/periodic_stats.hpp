// Logs one counters line per interval, for operators: the only regular log output of a role.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <functional>
#include <string>

namespace canbridge::bridge {

class PeriodicStats {
 public:
  // interval 0 disables.
  PeriodicStats(boost::asio::any_io_executor executor, std::chrono::seconds interval,
                std::function<std::string()> line);
  void stop() { timer_.cancel(); }

 private:
  void arm();
  boost::asio::steady_timer timer_;
  std::chrono::seconds interval_;
  std::function<std::string()> line_;
};

}  // namespace canbridge::bridge
