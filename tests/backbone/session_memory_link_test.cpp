// A real session pair over the in-memory link: the hello exchange, reliable payloads exactly once,
// and a stream that resumes on a new pair after one end closed the old one. No sockets: what
// these show about the session holds for any MessageLink.
#include <gtest/gtest.h>

#include <algorithm>
#include <boost/asio/io_context.hpp>

#include "backbone/memory_link.hpp"
#include "backbone/session.hpp"
#include "tests/backbone/session_peers.hpp"
#include "tests/backbone/test_support.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::exactly_once_in_order;
using testing::fast_options;
using testing::run_until;
using testing::SessionEnd;

// Nothing here tests the watchdog: a generous dead_after keeps a loaded machine (sanitizers, two
// test processes) from declaring a link dead while this process waits for the CPU.
SessionOptions patient_options() {
  SessionOptions o = fast_options();
  o.dead_after = 5s;
  return o;
}

class SessionOverMemoryLinkTest : public ::testing::Test {
 protected:
  MemoryLinkPair connect(MemoryLinkOptions options = {}) {
    auto pair = make_memory_link_pair(io.get_executor(), options);
    gateway.attach(pair.a);
    surface.attach(pair.b);
    return pair;
  }
  bool both_up() { return gateway.stream().up() && surface.stream().up(); }
  void TearDown() override {
    for (auto& l : gateway.links) l->close();
    for (auto& l : surface.links) l->close();
    io.restart();
    io.run_for(20ms);
  }

  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, patient_options(), {1, 2}};
  SessionEnd surface{"surface", v1::Hello::ROLE_SURFACE, patient_options()};
};

TEST_F(SessionOverMemoryLinkTest, HelloExchangeThenAReliablePayloadArrivesExactlyOnce) {
  const auto pair = connect();
  ASSERT_TRUE(run_until(io, [&] { return both_up(); }));
  EXPECT_EQ(surface.stream().peer_hello().name(), "gw");
  EXPECT_EQ(gateway.stream().peer_hello().role(), v1::Hello::ROLE_SURFACE);
  const auto& caps = gateway.stream().peer_hello().capabilities();
  EXPECT_NE(std::find(caps.begin(), caps.end(), "delimited"), caps.end());

  gateway.send_up_to(1);
  ASSERT_TRUE(run_until(io, [&] { return surface.received.size() == 1; }));
  // Acknowledged, and never delivered a second time however long the link runs on.
  ASSERT_TRUE(run_until(io, [&] { return gateway.stream().sender().unacked_count() == 0; }));
  io.restart();
  io.run_for(200ms);  // keepalives and acks go on meanwhile
  EXPECT_EQ(surface.received, std::vector<std::uint64_t>{1});
  EXPECT_GT(pair.a->counters().tx_writes, 1u);
  EXPECT_EQ(pair.a->counters().tx_bytes, pair.b->counters().rx_bytes);
  EXPECT_EQ(surface.ups, 1);
  EXPECT_EQ(gateway.downs + surface.downs, 0);
}

TEST_F(SessionOverMemoryLinkTest, ACrcFramedPairMakesTheSessionBehaveAsOverSerial) {
  MemoryLinkOptions options;
  options.crc_framed = true;
  connect(options);
  ASSERT_TRUE(run_until(io, [&] { return both_up(); }));
  const auto& caps = surface.stream().peer_hello().capabilities();
  EXPECT_NE(std::find(caps.begin(), caps.end(), "cobs-crc32c"), caps.end());
}

// One end closes (the other sees the link end); a new pair resumes the stream where it stood.
TEST_F(SessionOverMemoryLinkTest, ClosingOneEndAndAttachingANewPairResumesExactlyOnce) {
  MemoryLinkOptions options;
  options.capacity_bytes = 8 * 1024;  // a small window: plenty is in flight at every cut
  connect(options);
  for (int round = 1; round <= 5; ++round) {
    // Cut from inside the surface's receive handler, with the rest of the round in flight.
    // Alternate which end closes; the other learns it from its link.
    const std::uint64_t cut_at = 4000u * round - 2500;
    auto& closer = round % 2 ? gateway : surface;
    bool cut = false;
    surface.after_receive = [&, cut_at](std::uint64_t n) {
      if (n != cut_at) return;
      closer.links.back()->close();
      cut = true;
    };
    gateway.send_up_to(4000u * round);
    surface.send_up_to(1000u * round);
    ASSERT_TRUE(
        run_until(io, [&] { return cut && !gateway.stream().up() && !surface.stream().up(); }));
    EXPECT_FALSE(gateway.links.back()->message_link()->is_open());
    EXPECT_FALSE(surface.links.back()->message_link()->is_open());
    EXPECT_LT(surface.received.size(), 4000u * round);  // the cut came with payloads unsent
    connect(options);
  }
  surface.after_receive = nullptr;
  ASSERT_TRUE(run_until(io, [&] {
    return both_up() && surface.received.size() == 20000 && gateway.received.size() == 5000;
  }));
  EXPECT_TRUE(exactly_once_in_order(surface.received, 20000));
  EXPECT_TRUE(exactly_once_in_order(gateway.received, 5000));
  EXPECT_EQ(surface.corrupt + gateway.corrupt, 0u);
  EXPECT_EQ(surface.ups, 6);
  EXPECT_EQ(surface.downs, 5);
  EXPECT_EQ(gateway.counters.dead_links + surface.counters.dead_links, 0u);
}

// The session's own authentication over a real SessionLink: every link handshakes afresh, the
// link reports who the peer proved to be, and the reliable stream resumes on top as on a plain
// link.
SessionOptions authenticating(AuthRole role) {
  SessionOptions o = fast_options();
  o.authenticator = [role](const std::string&) {
    PeerAuthenticatorOptions a;
    a.role = role;
    a.own_identity = role == AuthRole::gateway ? "gw" : "surface";
    a.peer_identity = role == AuthRole::gateway ? "surface" : "gw";
    std::array<std::uint8_t, kPreSharedKeySize> key{};
    key.fill(7);
    a.keys.emplace_back(key);
    return std::make_unique<PeerAuthenticator>(std::move(a));
  };
  return o;
}

TEST(SessionAuthOverMemoryLinkTest, EveryLinkAuthenticatesAndTheStreamResumesExactlyOnce) {
  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, authenticating(AuthRole::gateway), {1}};
  SessionEnd surface{"surface", v1::Hello::ROLE_SURFACE, authenticating(AuthRole::surface)};
  MemoryLinkOptions options;
  options.crc_framed = true;
  for (std::uint64_t round = 1; round <= 3; ++round) {
    auto pair = make_memory_link_pair(io.get_executor(), options);
    auto g = gateway.attach(pair.a);
    auto s = surface.attach(pair.b);
    ASSERT_TRUE(run_until(io, [&] { return g->ready() && s->ready(); })) << round;
    EXPECT_EQ(g->authenticated_peer(), "surface");
    EXPECT_EQ(s->authenticated_peer(), "gw");
    gateway.send_up_to(round * 100);
    ASSERT_TRUE(run_until(io, [&] { return surface.received.size() >= round * 100 - 50; }));
    pair.b->close();  // cut mid-stream
    ASSERT_TRUE(run_until(io, [&] { return !gateway.stream().up() && !surface.stream().up(); }));
  }
  auto pair = make_memory_link_pair(io.get_executor(), options);
  auto g = gateway.attach(pair.a);
  auto s = surface.attach(pair.b);
  ASSERT_TRUE(run_until(io, [&] {
    return g->ready() && s->ready() && surface.received.size() == 300 &&
           gateway.stream().sender().unacked_count() == 0;
  }));
  EXPECT_TRUE(exactly_once_in_order(surface.received, 300));
  EXPECT_EQ(surface.counters.auth_established, 4u);
  EXPECT_EQ(gateway.counters.auth_established, 4u);
  EXPECT_EQ(surface.counters.rejected_bad_tag + surface.counters.rejected_replay, 0u);
  pair.a->close();
  io.restart();
  io.run_for(20ms);
}

}  // namespace
}  // namespace canbridge::backbone
