// The seam between accepting or connecting a TCP socket and having a StreamLink on it: plain
// (wrap the socket), or a TLS 1.3 handshake that proves both ends first (backbone/tls_*).
#pragma once

#include <boost/asio/awaitable.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <functional>
#include <memory>
#include <system_error>

#include "backbone/stream_link.hpp"

namespace canbridge::backbone {

// What an upgrade made of a socket: a link (its authenticated_peer() says who proved what), or
// why there is none (the socket is closed then).
struct UpgradeResult {
  std::shared_ptr<StreamLink> link;
  std::error_code error;
};

// Turns a connected socket into a link. Must honour cancellation (the server's handshake
// deadline cancels it). Empty std::function: plain, StreamLink::create(socket, options).
using LinkUpgrade = std::function<boost::asio::awaitable<UpgradeResult>(
    boost::asio::ip::tcp::socket socket, StreamLinkOptions options)>;

}  // namespace canbridge::backbone
