#include "bridge/deadline_driver.hpp"

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <utility>

namespace canbridge::bridge {

namespace asio = boost::asio;

DeadlineDriver::DeadlineDriver(asio::any_io_executor executor, Now now)
    : timer_(std::move(executor)), now_(std::move(now)) {}

void DeadlineDriver::add(std::string name, NextDeadline next_deadline, OnDeadline on_deadline) {
  cores_.push_back({std::move(name), std::move(next_deadline), std::move(on_deadline)});
  reschedule();
}

std::optional<DeadlineDriver::TimePoint> DeadlineDriver::earliest() const {
  std::optional<TimePoint> first;
  for (const Core& core : cores_) {
    const std::optional<TimePoint> deadline = core.next_deadline();
    if (deadline && (!first || *deadline < *first)) first = deadline;
  }
  return first;
}

std::optional<DeadlineDriver::TimePoint> DeadlineDriver::fire_due(TimePoint now) {
  for (Core& core : cores_) {
    const std::optional<TimePoint> deadline = core.next_deadline();
    if (!deadline || *deadline > now) continue;
    ++counters_.deadlines;
    core.on_deadline(now);
  }
  return earliest();
}

void DeadlineDriver::reschedule() {
  if (!running_) return;  // the loop arms itself from earliest() when it gets there
  const std::optional<TimePoint> deadline = earliest();
  if (!deadline || *deadline >= armed_until_) return;
  ++counters_.rearms;
  armed_until_ = *deadline;  // a second reschedule before the loop re-arms does nothing more
  timer_.cancel();
}

asio::awaitable<void> DeadlineDriver::run() {
  std::optional<TimePoint> next = earliest();
  while (!stopped_) {
    armed_until_ = next.value_or(TimePoint::max());
    timer_.expires_at(armed_until_);
    running_ = true;
    auto [ec] = co_await timer_.async_wait(asio::as_tuple(asio::use_awaitable));
    running_ = false;
    if (stopped_) break;
    if (ec) {  // cancelled by reschedule(): an earlier deadline appeared
      next = earliest();
      continue;
    }
    ++counters_.wakeups;
    next = fire_due(now_());
  }
  armed_until_ = TimePoint::max();
}

void DeadlineDriver::stop() {
  stopped_ = true;
  timer_.cancel();
}

}  // namespace canbridge::bridge
