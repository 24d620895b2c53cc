// Helpers for backbone tests: drive one io_context until a condition holds, never by sleeping,
// and look at the sockets it made.
#pragma once

#include <gtest/gtest.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <chrono>
#include <cstdint>
#include <span>
#include <string>

#include "tests/support/event_loop.hpp"

namespace canbridge::backbone::testing {

using namespace std::chrono_literals;

using canbridge::test::drains_within;
using canbridge::test::run_until;

inline std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

inline std::string to_string(std::span<const std::uint8_t> s) {
  return {reinterpret_cast<const char*>(s.data()), s.size()};
}

// A connected pair of loopback sockets on `io`.
struct SocketPair {
  boost::asio::ip::tcp::socket client;
  boost::asio::ip::tcp::socket server;
};

inline SocketPair connected_sockets(boost::asio::io_context& io) {
  using boost::asio::ip::tcp;
  tcp::acceptor acceptor(io, tcp::endpoint(boost::asio::ip::address_v4::loopback(), 0));
  tcp::socket client(io);
  client.connect(acceptor.local_endpoint());  // completes from the listen backlog
  tcp::socket server = acceptor.accept();
  return {std::move(client), std::move(server)};
}

// A port on 127.0.0.1 where nothing listens (it was free a moment ago).
inline std::uint16_t unused_port(boost::asio::io_context& io) {
  using boost::asio::ip::tcp;
  tcp::acceptor acceptor(io, tcp::endpoint(boost::asio::ip::address_v4::loopback(), 0));
  return acceptor.local_endpoint().port();
}

// The TCP_NODELAY option of socket `fd` (nonzero: set).
inline int tcp_nodelay(int fd) {
  int value = 0;
  socklen_t length = sizeof value;
  EXPECT_EQ(::getsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &value, &length), 0);
  return value;
}

}  // namespace canbridge::backbone::testing
