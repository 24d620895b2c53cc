#include "can/link_watch.hpp"

#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>
#include <sys/socket.h>
#include <unistd.h>

#include <boost/asio/as_tuple.hpp>
#include <boost/asio/use_awaitable.hpp>
#include <cerrno>
#include <cstring>

namespace canbridge::can {

namespace asio = boost::asio;

std::vector<LinkEvent> parse_link_messages(std::span<const std::uint8_t> bytes) {
  std::vector<LinkEvent> events;
  std::size_t offset = 0;
  while (bytes.size() - offset >= sizeof(nlmsghdr)) {
    nlmsghdr header;
    std::memcpy(&header, bytes.data() + offset, sizeof header);
    if (header.nlmsg_len < sizeof(nlmsghdr) || header.nlmsg_len > bytes.size() - offset) break;
    if ((header.nlmsg_type == RTM_NEWLINK || header.nlmsg_type == RTM_DELLINK) &&
        header.nlmsg_len >= NLMSG_LENGTH(sizeof(ifinfomsg))) {
      ifinfomsg info;
      std::memcpy(&info, bytes.data() + offset + NLMSG_HDRLEN, sizeof info);
      const unsigned flags = info.ifi_flags;
      LinkEvent e;
      e.ifindex = static_cast<unsigned>(info.ifi_index);
      e.up =
          header.nlmsg_type == RTM_NEWLINK && (flags & IFF_UP) != 0 && (flags & IFF_RUNNING) != 0;
      events.push_back(e);
    }
    const std::size_t step = NLMSG_ALIGN(header.nlmsg_len);
    if (step > bytes.size() - offset) break;
    offset += step;
  }
  return events;
}

bool LinkWatch::open(std::error_code& ec) {
  ec.clear();
  const int fd = ::socket(AF_NETLINK, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, NETLINK_ROUTE);
  if (fd < 0) {
    ec = {errno, std::system_category()};
    return false;
  }
  sockaddr_nl addr{};
  addr.nl_family = AF_NETLINK;
  addr.nl_groups = RTMGRP_LINK;
  if (::bind(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    ec = {errno, std::system_category()};
    ::close(fd);
    return false;
  }
  boost::system::error_code assigned;
  socket_.assign(fd, assigned);
  if (assigned) {
    ec = {assigned.value(), std::system_category()};
    ::close(fd);
    return false;
  }
  return true;
}

asio::awaitable<std::error_code> LinkWatch::next(std::vector<LinkEvent>& events) {
  events.clear();
  for (;;) {
    if (!socket_.is_open()) co_return std::make_error_code(std::errc::operation_canceled);
    const ssize_t n = ::recv(socket_.native_handle(), buffer_.data(), buffer_.size(), MSG_DONTWAIT);
    if (n >= 0) {
      events = parse_link_messages({buffer_.data(), static_cast<std::size_t>(n)});
      co_return std::error_code{};
    }
    const int err = errno;
    if (err == EINTR) continue;
    // ENOBUFS: notifications were lost; the caller looks at the interface itself anyway.
    if (err == ENOBUFS) co_return std::error_code{};
    if (err != EAGAIN && err != EWOULDBLOCK) co_return std::error_code{err, std::system_category()};
    auto [ec] = co_await socket_.async_wait(asio::posix::stream_descriptor::wait_read,
                                            asio::as_tuple(asio::use_awaitable));
    if (ec) co_return std::make_error_code(std::errc::operation_canceled);
  }
}

void LinkWatch::close() {
  boost::system::error_code ignored;
  socket_.close(ignored);
}

}  // namespace canbridge::can
