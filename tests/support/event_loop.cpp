#include "tests/support/event_loop.hpp"

#include <boost/asio/steady_timer.hpp>

namespace canbridge::test {

using namespace std::chrono_literals;

bool run_until(boost::asio::io_context& io, const std::function<bool()>& done,
               std::chrono::milliseconds timeout) {
  if (done()) return true;
  // Checked on a 2 ms tick rather than after every handler: run_one_for() reads the clock per
  // handler, a system call in user-mode Linux that would slow the loop under test.
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  bool met = false;
  boost::asio::steady_timer tick(io);
  std::function<void()> arm = [&] {
    tick.expires_after(2ms);
    tick.async_wait([&](boost::system::error_code ec) {
      if (ec) return;
      met = done();
      if (met || std::chrono::steady_clock::now() > deadline) {
        io.stop();
      } else {
        arm();
      }
    });
  };
  arm();
  io.restart();
  io.run();
  // Let the tick's handler finish before `tick` and the captures go away.
  tick.cancel();
  io.restart();
  io.poll();
  return met || done();
}

}  // namespace canbridge::test
