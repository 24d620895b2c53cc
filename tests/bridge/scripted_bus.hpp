// A can::Bus for role tests whose receive does what the test scripts: wait until closed, throw,
// or return an error at once (a bus gone for good). It records whether the role closed it.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/as_tuple.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "can/bus.hpp"

namespace canbridge::test {

class ScriptedBus final : public can::Bus {
 public:
  enum class Receive { waits, throws, fails };

  ScriptedBus(boost::asio::any_io_executor executor, std::string name, Receive receive)
      : name_(std::move(name)), receive_(receive), wait_(executor) {
    wait_.expires_at(boost::asio::steady_timer::time_point::max());
  }

  const std::string& name() const override { return name_; }
  boost::asio::awaitable<std::error_code> receive_batch(std::vector<can::Frame>&) override {
    if (receive_ == Receive::throws) throw std::runtime_error("scripted receive failure");
    if (receive_ == Receive::fails) co_return std::make_error_code(std::errc::no_such_device);
    if (!closed_) {
      co_await wait_.async_wait(boost::asio::as_tuple(boost::asio::use_awaitable));
    }
    co_return std::make_error_code(std::errc::operation_canceled);
  }
  using can::Bus::send;  // the batch send: frame by frame through this one
  bool send(const can::Frame&) override { return !closed_; }
  std::size_t send_room() const override { return closed_ ? 0 : 64; }
  // Its 64 slots never fill (send() hands nothing to a driver), so room is there until it closes.
  boost::asio::awaitable<std::error_code> wait_send_room(std::size_t) override {
    co_return closed_ ? std::make_error_code(std::errc::operation_canceled) : std::error_code{};
  }
  can::BusCounters counters() const override { return {}; }
  void on_state_change(std::function<void(can::BusState)>) override {}
  void close() override {
    closed_ = true;
    wait_.cancel();
  }

  bool closed() const { return closed_; }

 private:
  std::string name_;
  Receive receive_;
  boost::asio::steady_timer wait_;
  bool closed_ = false;
};

}  // namespace canbridge::test
