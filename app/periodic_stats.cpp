#include "app/periodic_stats.hpp"

#include <spdlog/spdlog.h>

namespace canbridge::bridge {

PeriodicStats::PeriodicStats(boost::asio::any_io_executor executor, std::chrono::seconds interval,
                             std::function<std::string()> line)
    : timer_(std::move(executor)), interval_(interval), line_(std::move(line)) {
  if (interval_.count() > 0) arm();
}

void PeriodicStats::stop() {
  stopped_ = true;
  timer_.cancel();
}

void PeriodicStats::set_interval(std::chrono::seconds interval) {
  if (stopped_) return;
  interval_ = interval;
  timer_.cancel();  // the pending wait ends with operation_aborted and does not re-arm
  if (interval_.count() > 0) arm();
}

void PeriodicStats::arm() {
  timer_.expires_after(interval_);
  timer_.async_wait([this](boost::system::error_code ec) {
    if (ec) return;
    spdlog::info("{}", line_());
    arm();
  });
}

}  // namespace canbridge::bridge
