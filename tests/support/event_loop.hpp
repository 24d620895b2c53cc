// Driving an io_context from a test with a deadline.
#pragma once

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <functional>

namespace canbridge::test {

// Runs handlers until `done()` holds (true) or the deadline passes (false). `done()` is checked
// every 2 ms, so conditions outside the loop (child exits) are noticed too.
bool run_until(boost::asio::io_context& io, const std::function<bool()>& done,
               std::chrono::milliseconds timeout = std::chrono::milliseconds(5000));

// Runs the io_context until it has no work left; true if that happened within `timeout`, i.e.
// nothing was left pending (a stopped role's coroutines all saw their bus or link close).
inline bool drains_within(boost::asio::io_context& io, std::chrono::milliseconds timeout) {
  io.restart();
  io.run_for(timeout);
  return io.stopped();
}

}  // namespace canbridge::test
