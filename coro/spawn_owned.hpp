// Starts a coroutine that belongs to an owner, so that its end is never silent: whether it
// returned, returned an error or threw, the owner hears why and decides (a role stops in order,
// a bus closes and fails its reader). The one error policy for coroutines; it lives in coro/, a
// leaf below every layer that spawns them (can/, backbone/, bridge/, sim/, the processes).
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/bind_cancellation_slot.hpp>
#include <boost/asio/cancellation_signal.hpp>
#include <boost/asio/co_spawn.hpp>
#include <exception>
#include <string>
#include <system_error>
#include <type_traits>
#include <utility>

namespace canbridge::coro {

// The text of what a coroutine threw; empty for no exception.
inline std::string describe_exception(const std::exception_ptr& error) {
  if (!error) return {};
  try {
    std::rethrow_exception(error);
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "an exception of unknown type";
  }
}

// Runs `task` on `executor` (an executor or an io_context); when it ends, `on_end(reason)` runs
// with why: the text of the exception it threw, or empty when it returned. A coroutine that belongs
// to no one (detached) would take an exception, and with it the work it did, away without a word.
template <typename Executor, typename OnEnd>
void spawn_owned(Executor&& executor, boost::asio::awaitable<void> task, OnEnd on_end) {
  boost::asio::co_spawn(std::forward<Executor>(executor), std::move(task),
                        [on_end = std::move(on_end)](std::exception_ptr error) mutable {
                          on_end(describe_exception(error));
                        });
}

// The same for a coroutine function, e.g. a lambda whose captures its coroutine uses: co_spawn
// keeps the function object alive until the coroutine ends (a lambda called in place would be
// gone while its coroutine still reads its captures).
template <typename Executor, typename Function, typename OnEnd>
requires std::is_invocable_r_v<boost::asio::awaitable<void>, Function>
void spawn_owned(Executor&& executor, Function&& function, OnEnd on_end) {
  boost::asio::co_spawn(std::forward<Executor>(executor), std::forward<Function>(function),
                        [on_end = std::move(on_end)](std::exception_ptr error) mutable {
                          on_end(describe_exception(error));
                        });
}

// The same, cancellable: emitting on the signal that owns `slot` cancels what the coroutine is
// awaiting (e.g. a handshake past its deadline). That signal must outlive the coroutine.
template <typename Executor, typename OnEnd>
void spawn_owned(Executor&& executor, boost::asio::awaitable<void> task,
                 boost::asio::cancellation_slot slot, OnEnd on_end) {
  boost::asio::co_spawn(std::forward<Executor>(executor), std::move(task),
                        boost::asio::bind_cancellation_slot(
                            slot, [on_end = std::move(on_end)](std::exception_ptr error) mutable {
                              on_end(describe_exception(error));
                            }));
}

// The same for a loop that ends by returning an error (a bus gone for good): its message is the
// reason; empty when it threw nothing and returned no error.
template <typename Executor, typename OnEnd>
void spawn_owned(Executor&& executor, boost::asio::awaitable<std::error_code> task, OnEnd on_end) {
  boost::asio::co_spawn(
      std::forward<Executor>(executor), std::move(task),
      [on_end = std::move(on_end)](std::exception_ptr error, std::error_code ec) mutable {
        on_end(error ? describe_exception(error) : ec ? ec.message() : std::string());
      });
}

}  // namespace canbridge::coro
