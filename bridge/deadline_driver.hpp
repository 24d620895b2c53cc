// One timer per role: every core with deadlines registers here, and one loop sleeps until the
// earliest deadline any of them reports and hands each due core the same `now`.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace canbridge::bridge {

class DeadlineDriver {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  // The time handed to the cores. Injectable for tests; it must run with the steady clock the
  // timer sleeps on (a clock that lags it would wake the loop before any core is due).
  using Now = std::function<TimePoint()>;
  using NextDeadline = std::function<std::optional<TimePoint>()>;
  using OnDeadline = std::function<void(TimePoint now)>;

  struct Counters {
    std::uint64_t wakeups = 0;    // the timer expired (whether or not a core was due)
    std::uint64_t rearms = 0;     // reschedule() found an earlier deadline and woke the loop
    std::uint64_t deadlines = 0;  // on_deadline calls, all cores
  };

  explicit DeadlineDriver(boost::asio::any_io_executor executor, Now now = &Clock::now);

  // Registers a core. `next_deadline` is asked whenever the loop re-arms (and by reschedule()),
  // so it must be cheap; `on_deadline(now)` is called once per wake-up while the core's deadline
  // is at or before `now`, and must move it past `now` (or clear it).
  void add(std::string name, NextDeadline next_deadline, OnDeadline on_deadline);

  // The loop; its owner spawns it once (coro::spawn_owned). Returns after stop().
  boost::asio::awaitable<void> run();
  void stop();

  // After input to any core: wakes the loop to re-arm if some core's deadline is now earlier
  // than the one it sleeps until. Costs one next_deadline() per core, no timer operation when
  // nothing moved earlier.
  void reschedule();

  // Calls every core due at `now` (in the order they were added) and returns the earliest
  // deadline left. The loop's step, public so that tests drive it with a virtual clock.
  std::optional<TimePoint> fire_due(TimePoint now);
  // The earliest deadline of all cores; nullopt when none has one.
  std::optional<TimePoint> earliest() const;
  // The time the loop sleeps until (max when no core has a deadline, or before run()).
  TimePoint armed_until() const { return armed_until_; }
  TimePoint now() const { return now_(); }
  const Counters& counters() const { return counters_; }

 private:
  struct Core {
    std::string name;
    NextDeadline next_deadline;
    OnDeadline on_deadline;
  };

  boost::asio::steady_timer timer_;
  Now now_;
  std::vector<Core> cores_;
  TimePoint armed_until_ = TimePoint::max();
  bool running_ = false;  // the loop is waiting on timer_ (cancel wakes it)
  bool stopped_ = false;
  Counters counters_;
};

}  // namespace canbridge::bridge
