// Starts a test's coroutine the project's way (coro::spawn_owned): an exception it throws fails
// the running test with its text, where asio::detached would let it vanish with the check it was
// making.
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <utility>

#include "coro/spawn_owned.hpp"

namespace canbridge::test {

// `task`: an awaitable<void>, or a function returning one (its captures stay alive).
template <typename Executor, typename Task>
void spawn_checked(Executor&& executor, Task&& task) {
  coro::spawn_owned(std::forward<Executor>(executor), std::forward<Task>(task),
                    [](const std::string& why) {
                      if (!why.empty()) ADD_FAILURE() << "a test coroutine threw: " << why;
                    });
}

}  // namespace canbridge::test
