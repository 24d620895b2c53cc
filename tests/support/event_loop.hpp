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

}  // namespace canbridge::test
