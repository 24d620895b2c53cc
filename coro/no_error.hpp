// The completion token of the hot loops: an awaited operation returns its error_code (and
// results) as a tuple instead of throwing, so a loop handles errors as values (docs: no
// exceptions on the hot path). One definition for every file that awaits that way.
#pragma once

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/use_awaitable.hpp>

namespace canbridge::coro {

inline constexpr auto kNoError = boost::asio::as_tuple(boost::asio::use_awaitable);

}  // namespace canbridge::coro
