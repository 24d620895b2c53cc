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
  void stop();
  // A new interval from now on (a config reload); 0 disables, a positive one re-arms. Ignored
  // after stop().
  void set_interval(std::chrono::seconds interval);
  std::chrono::seconds interval() const { return interval_; }

 private:
  void arm();
  boost::asio::steady_timer timer_;
  std::chrono::seconds interval_;
  std::function<std::string()> line_;
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
