// The rtnetlink link message parser: bytes as the kernel sends them in, interface states out.
#include "can/link_watch.hpp"

#include <gtest/gtest.h>
#include <linux/netlink.h>
#include <linux/rtnetlink.h>
#include <net/if.h>

#include <cstring>

namespace canbridge::can {
namespace {

// One link message as the kernel lays it out: nlmsghdr, ifinfomsg, and `attribute_bytes` of
// attributes (zeros: the parser must skip what it does not read).
std::vector<std::uint8_t> link_message(std::uint16_t type, int index, unsigned flags,
                                       std::size_t attribute_bytes = 20) {
  const std::size_t length = NLMSG_LENGTH(sizeof(ifinfomsg)) + attribute_bytes;
  std::vector<std::uint8_t> bytes(NLMSG_ALIGN(length), 0);
  nlmsghdr header{};
  header.nlmsg_len = static_cast<std::uint32_t>(length);
  header.nlmsg_type = type;
  std::memcpy(bytes.data(), &header, sizeof header);
  ifinfomsg info{};
  info.ifi_family = AF_UNSPEC;
  info.ifi_index = index;
  info.ifi_flags = flags;
  std::memcpy(bytes.data() + NLMSG_HDRLEN, &info, sizeof info);
  return bytes;
}

std::vector<std::uint8_t> concat(std::vector<std::uint8_t> a, const std::vector<std::uint8_t>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

TEST(LinkMessages, UpNeedsBothUpAndRunning) {
  EXPECT_EQ(parse_link_messages(link_message(RTM_NEWLINK, 7, IFF_UP | IFF_RUNNING | IFF_NOARP)),
            (std::vector<LinkEvent>{{7, true}}));
  EXPECT_EQ(parse_link_messages(link_message(RTM_NEWLINK, 7, IFF_UP)),
            (std::vector<LinkEvent>{{7, false}}));
  EXPECT_EQ(parse_link_messages(link_message(RTM_NEWLINK, 7, IFF_NOARP)),
            (std::vector<LinkEvent>{{7, false}}));
}

TEST(LinkMessages, ARemovedInterfaceIsDown) {
  EXPECT_EQ(parse_link_messages(link_message(RTM_DELLINK, 3, IFF_UP | IFF_RUNNING)),
            (std::vector<LinkEvent>{{3, false}}));
}

TEST(LinkMessages, SeveralMessagesInOneDatagramOtherTypesSkipped) {
  auto bytes = concat(link_message(RTM_NEWLINK, 4, 0, 3),  // odd length: padded to 4
                      link_message(RTM_NEWADDR, 4, IFF_UP | IFF_RUNNING));
  bytes = concat(bytes, link_message(RTM_NEWLINK, 5, IFF_UP | IFF_RUNNING));
  EXPECT_EQ(parse_link_messages(bytes), (std::vector<LinkEvent>{{4, false}, {5, true}}));
}

TEST(LinkMessages, TruncatedOrMalformedInputIsSkippedWithoutReadingPastIt) {
  const auto whole = link_message(RTM_NEWLINK, 9, IFF_UP | IFF_RUNNING);
  for (std::size_t n = 0; n < whole.size(); ++n) {
    const std::vector<std::uint8_t> part(whole.begin(), whole.begin() + static_cast<long>(n));
    EXPECT_TRUE(parse_link_messages(part).empty()) << n << " bytes";
  }
  // A header claiming fewer bytes than a header, or more than the datagram: stop there.
  auto bad = whole;
  const std::uint32_t tiny = 4;
  std::memcpy(bad.data(), &tiny, sizeof tiny);
  EXPECT_TRUE(parse_link_messages(bad).empty());
  const std::uint32_t huge = 4096;
  std::memcpy(bad.data(), &huge, sizeof huge);
  EXPECT_TRUE(parse_link_messages(bad).empty());
  // A link message too short for its ifinfomsg is not a link event.
  auto short_link = link_message(RTM_NEWLINK, 9, IFF_UP, 0);
  const auto len = static_cast<std::uint32_t>(NLMSG_HDRLEN + 4);
  std::memcpy(short_link.data(), &len, sizeof len);
  EXPECT_TRUE(parse_link_messages(short_link).empty());
}

}  // namespace
}  // namespace canbridge::can
