// Learns from the kernel's rtnetlink link notifications (RTMGRP_LINK) when a network interface
// goes down or comes up again, so a bus that lost its interface reopens it at once.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <boost/asio/posix/stream_descriptor.hpp>
#include <cstdint>
#include <span>
#include <system_error>
#include <vector>

namespace canbridge::can {

// One interface's state as a link message announces it.
struct LinkEvent {
  unsigned ifindex = 0;
  bool up = false;  // IFF_UP and IFF_RUNNING; false for a removed interface (RTM_DELLINK)
  friend bool operator==(const LinkEvent&, const LinkEvent&) = default;
};

// The link events in one datagram read from an rtnetlink socket (RTM_NEWLINK, RTM_DELLINK; any
// other message, and anything truncated or malformed, is skipped). Never reads past `bytes`.
std::vector<LinkEvent> parse_link_messages(std::span<const std::uint8_t> bytes);

// A non-blocking AF_NETLINK/NETLINK_ROUTE socket subscribed to RTMGRP_LINK, on the event loop.
class LinkWatch {
 public:
  explicit LinkWatch(boost::asio::any_io_executor executor) : socket_(std::move(executor)) {}
  // Opens and subscribes; false (ec set) where netlink is not available.
  bool open(std::error_code& ec);
  // Waits for the next datagram and returns its events (empty on a datagram with none); an
  // error once closed or on a socket failure.
  boost::asio::awaitable<std::error_code> next(std::vector<LinkEvent>& events);
  void close();
  bool is_open() const { return socket_.is_open(); }

 private:
  boost::asio::posix::stream_descriptor socket_;
  std::vector<std::uint8_t> buffer_ = std::vector<std::uint8_t>(16384);
};

}  // namespace canbridge::can
