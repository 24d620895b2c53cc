// spawn_owned: the owner of a coroutine hears how it ended, whether it returned, returned an
// error or threw.
#include "coro/spawn_owned.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/this_coro.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <optional>
#include <stdexcept>
#include <string>

namespace canbridge::coro {
namespace {

namespace asio = boost::asio;

std::optional<std::string> end_of(asio::awaitable<void> task, asio::io_context& io) {
  std::optional<std::string> reason;
  spawn_owned(io, std::move(task), [&](const std::string& why) { reason = why; });
  io.run();
  return reason;
}

TEST(SpawnOwned, AReturnEndsWithAnEmptyReason) {
  asio::io_context io;
  auto task = []() -> asio::awaitable<void> { co_return; };
  EXPECT_EQ(end_of(task(), io), std::string());
}

TEST(SpawnOwned, AThrowEndsWithTheExceptionsText) {
  asio::io_context io;
  auto task = []() -> asio::awaitable<void> {
    throw std::runtime_error("reader broke");
    co_return;
  };
  EXPECT_EQ(end_of(task(), io), std::string("reader broke"));
}

TEST(SpawnOwned, AnErrorReturnEndsWithItsMessage) {
  asio::io_context io;
  std::optional<std::string> reason;
  auto task = []() -> asio::awaitable<std::error_code> {
    co_return std::make_error_code(std::errc::no_such_device);
  };
  spawn_owned(io, task(), [&](const std::string& why) { reason = why; });
  io.run();
  EXPECT_EQ(reason, std::make_error_code(std::errc::no_such_device).message());

  reason.reset();
  auto fine = []() -> asio::awaitable<std::error_code> { co_return std::error_code{}; };
  spawn_owned(io, fine(), [&](const std::string& why) { reason = why; });
  io.restart();
  io.run();
  EXPECT_EQ(reason, std::string());
}

// A coroutine function (a lambda with captures) is kept alive while its coroutine runs: the
// captures are read after the first suspension, when a lambda called in place would be gone.
TEST(SpawnOwned, ALambdaKeepsItsCapturesUntilItsCoroutineEnds) {
  asio::io_context io;
  std::optional<std::string> reason;
  std::string seen;
  spawn_owned(
      io,
      [text = std::string(64, 'x'), &seen]() -> asio::awaitable<void> {
        co_await asio::post(co_await asio::this_coro::executor, asio::use_awaitable);
        seen = text;
        throw std::runtime_error("after " + std::to_string(text.size()));
      },
      [&](const std::string& why) { reason = why; });
  io.run();
  EXPECT_EQ(seen, std::string(64, 'x'));
  EXPECT_EQ(reason, std::string("after 64"));
}

TEST(SpawnOwned, AnExceptionOfAnyTypeIsStillReported) {
  asio::io_context io;
  auto task = []() -> asio::awaitable<void> {
    throw 42;
    co_return;
  };
  EXPECT_EQ(end_of(task(), io), std::string("an exception of unknown type"));
}

}  // namespace
}  // namespace canbridge::coro
