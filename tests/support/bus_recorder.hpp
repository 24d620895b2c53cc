// Records every frame a can::Bus endpoint receives, so in-process tests can drive a bus and check
// what reached it.
#pragma once

#include <algorithm>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/co_spawn.hpp>
#include <boost/asio/io_context.hpp>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "can/bus.hpp"
#include "can/frame.hpp"
#include "tests/support/spawn_checked.hpp"

namespace canbridge::test {

// Receives from its bus endpoint in a coroutine that runs until the bus closes; `on_frames`
// (optional) runs after each received batch. close() and then waiting for done() must precede
// destruction (the coroutine uses the bus).
class BusRecorder {
 public:
  BusRecorder(boost::asio::io_context& io, std::unique_ptr<can::Bus> bus) : bus_(std::move(bus)) {
    test::spawn_checked(io, [this]() -> boost::asio::awaitable<void> {
      while (!co_await bus_->receive_batch(frames)) {
        if (on_frames) on_frames();
      }
      done_ = true;
    });
  }
  bool send(const can::Frame& f) { return bus_->send(f); }
  void close() { bus_->close(); }
  bool done() const { return done_; }
  std::size_t count(std::uint32_t id) const {
    return static_cast<std::size_t>(std::count_if(frames.begin(), frames.end(),
                                                  [&](const can::Frame& f) { return f.id == id; }));
  }
  bool saw(const can::Frame& frame) const {
    return std::find(frames.begin(), frames.end(), frame) != frames.end();
  }

  std::vector<can::Frame> frames;
  std::function<void()> on_frames;

 private:
  std::unique_ptr<can::Bus> bus_;
  bool done_ = false;
};

}  // namespace canbridge::test
