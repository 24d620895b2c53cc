// The session protocol against a scripted peer over an in-memory link: a real SessionLink and
// PeerStream (a gateway end) on one side, a script playing the surface envelope by envelope on
// the other, so each rule of the protocol is checked on the wire: who says hello first, what a
// refusal does, when keepalives go out, what a resend request brings back, when silence kills a
// link, what a broken write costs on the next link, and what a restarted peer no longer gets.
#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
#include "backbone/session.hpp"
#include "tests/backbone/envelopes.hpp"
#include "tests/backbone/scripted_peer.hpp"
#include "tests/backbone/session_peers.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::backbone {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using testing::any_keepalive;
using testing::hello;
using testing::hello_from;
using testing::keepalive;
using testing::keepalive_acking;
using testing::payload;
using testing::payload_seq;
using testing::PeerIdentity;
using testing::PeerScript;
using testing::refusal;
using testing::refusal_for;
using testing::resend_request;
using testing::ScriptedPeer;
using testing::SessionEnd;
using testing::tombstone_seq;

constexpr auto kKeepalive = 100ms;

// Keepalives often enough to time them, and nothing else on its own: no dead link within a test
// unless the test shortens dead_after, no retransmission unless asked for.
SessionOptions scripted_options() {
  SessionOptions o;
  o.keepalive_interval = kKeepalive;
  o.dead_after = 5s;
  o.retransmit_timeout = 10s;
  o.resend_buffer_messages = 64;
  o.resend_buffer_bytes = 64 * 1024;
  return o;
}

// The payloads SessionEnd sends: its number, 8 bytes little endian.
std::string numbered(std::uint64_t n) {
  std::string p(8, '\0');
  for (std::size_t i = 0; i < 8; ++i) p[i] = static_cast<char>((n >> (8 * i)) & 0xFF);
  return p;
}

// An idle side's keepalive: one interval after its last envelope, give or take the watchdog's
// tick (a quarter interval) and a loaded machine's latency.
PeerScript& idle_keepalive(PeerScript& script, std::uint64_t ack) {
  return script.expect(keepalive_acking(ack)).within(kKeepalive * 8 / 10, kKeepalive * 2);
}

class SessionScript : public ::testing::Test {
 protected:
  // A fresh memory pair: end a for the gateway under test, end b for the script.
  MemoryLinkPair pair(const char* name = "backbone") {
    MemoryLinkOptions options;
    options.name = name;
    return make_memory_link_pair(io.get_executor(), options);
  }
  // The gateway's hello and the surface's answer: the link is ready on both ends after it.
  PeerScript& handshake(PeerScript& script) {
    return script.expect(hello_from(v1::Hello::ROLE_GATEWAY))
        .reply(hello(surface))
        .wait_for("the gateway's link is ready", [this] { return gateway.stream().up(); });
  }
  void TearDown() override {
    for (auto& l : gateway.links) l->close();
    io.restart();
    io.run_for(20ms);
  }

  asio::io_context io{1};
  SessionEnd gateway{"gw", v1::Hello::ROLE_GATEWAY, scripted_options(), {1, 2}};
  PeerIdentity surface{v1::Hello::ROLE_SURFACE, "scripted-surface", 0x51, {}, {}};
};

TEST_F(SessionScript, TheGatewaySaysHelloFirstAndIsReadyOnlyAfterTheSurfacesHello) {
  const std::uint64_t gw_session = gateway.identity().session_id;
  PeerScript script;
  script
      .expect(hello_from(
          v1::Hello::ROLE_GATEWAY,
          [&](const v1::Hello& h) {
            return h.name() == "gw" && h.module_ids_size() == 2 && h.session_id() == gw_session &&
                   h.resume_session_id() == 0 && h.send_base() == 1 &&
                   h.protocol_major() == kProtocolMajor;
          },
          "named gw, modules 1 and 2, a fresh stream"))
      // Unanswered, it says hello again one keepalive interval later (a hello may be lost).
      .expect(hello_from(v1::Hello::ROLE_GATEWAY))
      .within(kKeepalive * 8 / 10, kKeepalive * 2)
      .check("the gateway is not ready without the surface's hello",
             [&] { return !gateway.stream().up() && gateway.ups == 0; })
      .reply(hello(surface))
      .wait_for("the gateway's link is ready", [&] { return gateway.stream().up(); })
      .check("it knows the surface by its hello",
             [&] {
               return gateway.ups == 1 &&
                      gateway.stream().peer_hello().name() == "scripted-surface" &&
                      gateway.stream().peer_hello().session_id() == surface.session_id;
             })
      .act("the gateway sends a payload", [&] { gateway.send_up_to(1); })
      .expect(payload_seq(1, numbered(1)));
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  gateway.attach(link.a);
  EXPECT_TRUE(peer.finishes(io));
}

TEST_F(SessionScript, ARefusalIsReportedAndTheLinkCloses) {
  PeerScript script;
  script.expect(hello_from(v1::Hello::ROLE_GATEWAY))
      .reply(refusal(v1::Refusal::DUPLICATE_MODULE, "module 1 is served by 'other-gw'"))
      .expect_closed()
      .within(0ms, 1s);
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  gateway.attach(link.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(gateway.counters.refusals_received, 1u);
  EXPECT_EQ(gateway.ups, 0);
  // Its client sees why, and backs off as after a failed attempt.
  EXPECT_EQ(link.a->counters().close_reason, make_error_code(errc::refused_by_peer));
}

// The surface end refuses a peer of another major version before it closes; a peer that proved
// nothing (this memory link proves nothing) is told only that it was refused.
TEST_F(SessionScript, TheSurfaceRefusesAGatewayOfAnotherMajorVersionTellingItOnlyThat) {
  SessionEnd surface_end{"surface", v1::Hello::ROLE_SURFACE, scripted_options()};
  PeerIdentity future{v1::Hello::ROLE_GATEWAY, "future-gw", 0x77, {3}, {}};
  future.protocol_major = kProtocolMajor + 1;
  PeerScript script;
  script.reply(hello(future))
      .expect(refusal_for(v1::Refusal::REASON_UNSPECIFIED, {"refused"}))
      .expect_closed();
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  surface_end.attach(link.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(surface_end.counters.refusals_sent, 1u);
  EXPECT_EQ(surface_end.ups, 0);
  for (auto& l : surface_end.links) l->close();
}

TEST_F(SessionScript, AKeepaliveCarryingTheAckFollowsKeepaliveIntervalOfIdleness) {
  PeerScript script;
  handshake(script)
      .reply(payload(1, numbered(7)))
      // The payload is acknowledged at once, on its own...
      .expect(keepalive_acking(1))
      .within(0ms, kKeepalive / 2);
  // ... and then, idle, the gateway says it is alive once per interval, with the same ack.
  idle_keepalive(script, 1);
  idle_keepalive(script, 1);
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  gateway.attach(link.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(gateway.received, std::vector<std::uint64_t>{7});
  EXPECT_EQ(gateway.counters.keepalives_sent, 3u);
}

// The request names 2 (after its ack) and 3 (listed); 4 arrived. A listed hole is resent only
// once its last copy is a resend interval (a quarter of the retransmit timeout) old, as that copy
// may still be on its way: the script asks after that.
TEST_F(SessionScript, AResendRequestGetsExactlyTheMissingPayloadsAgain) {
  SessionOptions options = scripted_options();
  options.retransmit_timeout = 400ms;
  SessionEnd gw{"gw", v1::Hello::ROLE_GATEWAY, options, {1}};
  PeerScript script;
  script.expect(hello_from(v1::Hello::ROLE_GATEWAY))
      .reply(hello(surface))
      .wait_for("the gateway's link is ready", [&] { return gw.stream().up(); })
      .tolerate(any_keepalive())  // while the script waits, the gateway's idle keepalives
      .act("the gateway sends four payloads", [&] { gw.send_up_to(4); })
      .expect(payload_seq(1, numbered(1)))
      .expect(payload_seq(2, numbered(2)))
      .expect(payload_seq(3, numbered(3)))
      .expect(payload_seq(4, numbered(4)))
      .after(options.retransmit_timeout / 4 + 20ms)
      .reply(resend_request(1, {3}))
      .expect(payload_seq(2, numbered(2)))
      .expect(payload_seq(3, numbered(3)))
      .reply(keepalive(4));
  // Nothing else again: the next envelope is the idle keepalive (a payload is not tolerated).
  idle_keepalive(script, 0);
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  gw.attach(link.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(gw.counters.reliable_resent, 2u);
  EXPECT_EQ(gw.stream().sender().unacked_count(), 0u);
}

TEST_F(SessionScript, SilencePastDeadAfterClosesTheLink) {
  SessionOptions options = scripted_options();
  options.dead_after = 400ms;
  SessionEnd gw{"gw", v1::Hello::ROLE_GATEWAY, options, {1}};
  PeerScript script;
  script.expect(hello_from(v1::Hello::ROLE_GATEWAY))
      .reply(hello(surface))
      .tolerate(any_keepalive());
  // A peer that speaks up every 250 ms keeps the link, for longer than dead_after in all...
  for (int i = 0; i < 3; ++i) script.after(250ms).reply(keepalive(0));
  script
      .check("the link is still up after 750 ms", [&] { return gw.stream().up(); })
      // ... and one silent for dead_after loses it, within a watchdog tick or so.
      .expect_closed()
      .within(400ms, 400ms + 200ms);
  auto link = pair();
  ScriptedPeer peer(link.b, std::move(script));
  gw.attach(link.a);
  ASSERT_TRUE(peer.finishes(io));
  EXPECT_EQ(gw.counters.dead_links, 1u);
  EXPECT_EQ(gw.downs, 1);
}

// The gateway's write carrying its ack of the surface's payload 1 is lost and breaks the link; on
// the next link each side's unacknowledged payload goes again, and each arrives once.
TEST_F(SessionScript, ABrokenWriteCostsNothingTwiceOnTheNextLink) {
  const std::uint64_t gw_session = gateway.identity().session_id;
  PeerScript first;
  handshake(first)
      .act("the gateway sends two payloads", [&] { gateway.send_up_to(2); })
      .expect(payload_seq(1, numbered(1)))
      .expect(payload_seq(2, numbered(2)))
      .fail_write(1)
      // Acknowledges the gateway's 1 (not 2) and sends the surface's 1.
      .reply(payload(1, numbered(101), 1))
      .expect_closed()
      .check("the gateway got the surface's payload once",
             [&] { return gateway.received == std::vector<std::uint64_t>{101}; })
      .wait_for("the gateway's stream is down", [&] { return !gateway.stream().up(); });
  auto link1 = pair("first");
  ScriptedPeer peer1(link1.b, std::move(first));
  gateway.attach(link1.a);
  ASSERT_TRUE(peer1.finishes(io));

  PeerScript second;
  second
      .expect({"a hello resuming the surface's stream after 1, sending from 2",
               [&](const v1::Envelope& e) {
                 return e.has_hello() && e.hello().resume_session_id() == surface.session_id &&
                        e.ack() == 1 && e.hello().send_base() == 2;
               }})
      // The surface has the gateway's 1 only (its 2 was in flight), and never saw the ack of its
      // own 1, so it sends that again.
      .reply(hello(surface, gw_session, 1))
      .reply(payload(1, numbered(101), 1))
      .tolerate(any_keepalive())
      .expect(payload_seq(2, numbered(2)))
      .reply(keepalive(2))
      .quiet_for(kKeepalive * 3)
      .check("the surface's payload was delivered once, its repeat counted",
             [&] {
               return gateway.received == std::vector<std::uint64_t>{101} &&
                      gateway.counters.reliable_duplicates == 1;
             })
      .check("the gateway holds nothing unacknowledged",
             [&] { return gateway.stream().sender().unacked_count() == 0; });
  auto link2 = pair("second");
  ScriptedPeer peer2(link2.b, std::move(second));
  gateway.attach(link2.a);
  ASSERT_TRUE(peer2.finishes(io));
  // Every envelope after the hello acknowledged the surface's 1, the repeat included.
  for (const auto& r : peer2.received()) EXPECT_EQ(r.envelope.ack(), 1u);
}

// A surface that comes back as a new process (a new session id in its hello) never gets what the
// gateway sent its previous process: those payloads become tombstones, and its own stream starts
// afresh at its send_base.
TEST_F(SessionScript, APeerHelloWithANewSessionIdDropsWhatTheOldProcessWasSent) {
  PeerScript first;
  handshake(first)
      .reply(payload(1, numbered(201)))
      .act("the gateway sends three payloads", [&] { gateway.send_up_to(3); })
      .tolerate(any_keepalive())
      .expect(payload_seq(1, numbered(1)))
      .expect(payload_seq(2, numbered(2)))
      .expect(payload_seq(3, numbered(3)))
      .close()
      .wait_for("the gateway's stream is down", [&] { return !gateway.stream().up(); });
  auto link1 = pair("first");
  ScriptedPeer peer1(link1.b, std::move(first));
  gateway.attach(link1.a);
  ASSERT_TRUE(peer1.finishes(io));

  PeerIdentity restarted = surface;
  restarted.session_id = 0x52;
  PeerScript second;
  second
      .expect(hello_from(
          v1::Hello::ROLE_GATEWAY,
          [&](const v1::Hello& h) {
            return h.resume_session_id() == surface.session_id && h.send_base() == 1;
          },
          "resuming the old surface process"))
      .reply(hello(restarted))
      .tolerate(any_keepalive())
      .expect(tombstone_seq(1))
      .expect(tombstone_seq(2))
      .expect(tombstone_seq(3))
      .reply(payload(1, numbered(301)))
      .act("the gateway sends one more", [&] { gateway.send_up_to(4); })
      .expect(payload_seq(4, numbered(4)))
      .quiet_for(kKeepalive * 2);
  auto link2 = pair("second");
  ScriptedPeer peer2(link2.b, std::move(second));
  gateway.attach(link2.a);
  ASSERT_TRUE(peer2.finishes(io));
  EXPECT_EQ(gateway.peer_restarts, 1);
  EXPECT_EQ(gateway.counters.reliable_dropped_peer_restart, 3u);
  ASSERT_EQ(gateway.dropped.size(), 3u);
  for (const auto& d : gateway.dropped) EXPECT_EQ(d.why, ReliableDrop::peer_restart);
  // The new process's payload 1 is news, not a duplicate of the old one's.
  EXPECT_EQ(gateway.counters.reliable_duplicates, 0u);
  EXPECT_EQ(gateway.received, (std::vector<std::uint64_t>{201, 301}));
}

// The harness itself: a script that waits for what never comes fails at the deadline naming the
// step, and one that gets something else fails at once naming what came.
TEST_F(SessionScript, AScriptFailsNamingTheStepItStalledOnOrWhatCameInstead) {
  PeerScript stalls;
  handshake(stalls).tolerate(any_keepalive()).expect(refusal_for(v1::Refusal::WRONG_ROLE));
  auto link1 = pair("first");
  ScriptedPeer peer1(link1.b, std::move(stalls));
  gateway.attach(link1.a);
  const ::testing::AssertionResult stalled = peer1.finishes(io, 300ms);
  ASSERT_FALSE(stalled);
  EXPECT_NE(std::string(stalled.message()).find("step 5 of 5 (a refusal WRONG_ROLE)"),
            std::string::npos)
      << stalled.message();
  EXPECT_NE(std::string(stalled.message()).find("still waiting after 300 ms"), std::string::npos)
      << stalled.message();

  PeerScript mismatches;
  mismatches.expect(payload_seq(1, numbered(1)));
  auto link2 = pair("second");
  ScriptedPeer peer2(link2.b, std::move(mismatches));
  gateway.attach(link2.a);
  const ::testing::AssertionResult wrong = peer2.finishes(io, 1s);
  ASSERT_FALSE(wrong);
  EXPECT_NE(std::string(wrong.message()).find("step 1 of 1 (payload seq 1 (8 bytes)): got hello"),
            std::string::npos)
      << wrong.message();
}

}  // namespace
}  // namespace canbridge::backbone
