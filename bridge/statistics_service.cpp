#include "bridge/statistics_service.hpp"

#include "bridge/statistics_text.hpp"

namespace canbridge::bridge {

StatisticsService::StatisticsService(boost::asio::any_io_executor executor,
                                     std::function<RoleStatistics()> snapshot,
                                     std::chrono::milliseconds interval)
    : timer_(std::move(executor)), snapshot_(std::move(snapshot)), interval_(interval) {}

void StatisticsService::start() {
  meter_.sample(snapshot_());
  arm();
}

void StatisticsService::arm() {
  timer_.expires_after(interval_);
  timer_.async_wait([this](boost::system::error_code ec) {
    if (ec) return;
    meter_.sample(snapshot_());
    arm();
  });
}

std::string StatisticsService::line() const {
  return statistics_line(snapshot_(), meter_.rates());
}

std::string StatisticsService::json() const {
  return statistics_json(snapshot_(), meter_.rates());
}

std::string StatisticsService::prometheus() const {
  return statistics_prometheus(snapshot_());
}

}  // namespace canbridge::bridge
