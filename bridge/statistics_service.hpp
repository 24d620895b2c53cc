// A role's statistics on demand: samples the role's snapshot once per interval so rates always
// cover a whole interval, and renders it as the periodic line, JSON and Prometheus text.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <functional>
#include <string>

#include "bridge/role_statistics.hpp"

namespace canbridge::bridge {

class StatisticsService {
 public:
  // `snapshot` is the role's statistics() (called on the executor's thread).
  StatisticsService(boost::asio::any_io_executor executor, std::function<RoleStatistics()> snapshot,
                    std::chrono::milliseconds interval = std::chrono::seconds(1));
  void start();  // takes the first sample and arms the timer
  void stop() { timer_.cancel(); }

  std::string line() const;        // the short periodic log line
  std::string json() const;        // `canbridge stats`
  std::string prometheus() const;  // GET /metrics
  RoleRates rates() const { return meter_.rates(); }

 private:
  void arm();
  boost::asio::steady_timer timer_;
  std::function<RoleStatistics()> snapshot_;
  std::chrono::milliseconds interval_;
  RateMeter meter_;
};

}  // namespace canbridge::bridge
