// Two session cores that authenticate (SessionOptions::authenticator) wired back to back with an
// injected clock: the challenge-response before the hellos, sealed envelopes after it, and what
// a hostile line does to them (tampered, replayed, truncated, reordered), without sockets.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <deque>
#include <functional>
#include <numeric>
#include <optional>
#include <random>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/envelope_codec.hpp"
#include "backbone/session_core.hpp"
#include "tests/backbone/session_core_payloads.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace canbridge::backbone {
namespace {

using namespace std::chrono_literals;
using TimePoint = SessionCore::TimePoint;
using testing::bytes_of;
using testing::number;
using testing::range;
using testing::split;

PreSharedKey test_key(std::uint8_t seed) {
  std::array<std::uint8_t, kPreSharedKeySize> b{};
  std::iota(b.begin(), b.end(), seed);
  return PreSharedKey(b);
}

// Records what the core asks of its link; counts binds (an unproven peer must never get one).
class BindCountingShell final : public SessionShell {
 public:
  void wake_writer() override {}
  void close_link(std::error_code reason) override {
    if (!closed) closed = reason;
  }
  void pause_reading(bool) override {}
  BindResult bind(const v1::Hello&) override {
    ++binds;
    return {bind_to, v1::Refusal::PROTOCOL_ERROR, {}};
  }
  void carry(PeerStream& stream) override { carried = &stream; }

  std::optional<std::error_code> closed;
  PeerStream* bind_to = nullptr;
  PeerStream* carried = nullptr;
  int binds = 0;
};

struct AuthKeys {
  std::vector<PreSharedKey> keys;
  std::string own;
  std::string peer;
};

struct AuthEnd {
  AuthEnd(std::string name, v1::Hello::Role role) : stream(options, handlers()) {
    options.keepalive_interval = 100ms;
    options.dead_after = 1000ms;
    options.retransmit_timeout = 400ms;
    options.resend_buffer_messages = 256;
    options.resend_buffer_bytes = 64 * 1024;
    identity.role = role;
    identity.expected_peer =
        role == v1::Hello::ROLE_GATEWAY ? v1::Hello::ROLE_SURFACE : v1::Hello::ROLE_GATEWAY;
    identity.name = name;
    identity.session_id = role == v1::Hello::ROLE_GATEWAY ? 11 : 22;
  }

  // This end authenticates with `keys` (own identity, the peer's), as the app configures it.
  void authenticate(AuthKeys keys) {
    const AuthRole role =
        identity.role == v1::Hello::ROLE_GATEWAY ? AuthRole::gateway : AuthRole::surface;
    options.authenticator = [role, keys](const std::string&) {
      PeerAuthenticatorOptions o;
      o.role = role;
      o.own_identity = keys.own;
      o.peer_identity = keys.peer;
      o.keys = keys.keys;
      return std::make_unique<PeerAuthenticator>(std::move(o));
    };
  }

  PeerStream::Handlers handlers() {
    return {[this](PayloadSink& sink) {
              while (!to_send.empty() && sink.room() > 0 && sink.reliable_room(8)) {
                sink.send_reliable(number(to_send.front()));
                to_send.pop_front();
              }
            },
            [this](std::span<const std::uint8_t> p, bool) {
              std::uint64_t n = 0;
              std::memcpy(&n, p.data(), std::min<std::size_t>(8, p.size()));
              received.push_back(n);
            },
            [this](const v1::Hello&) { ++ups; }, [this] { ++downs; }};
  }

  void open_link(TimePoint now, bool crc_framed) {
    if (core) core->on_link_closed(core->ready(), "replaced");
    shell = BindCountingShell{};
    shell.bind_to = &stream;
    const bool gateway = identity.role == v1::Hello::ROLE_GATEWAY;
    core.emplace(identity, options, gateway ? &stream : nullptr, counters, log, shell,
                 SessionCore::LinkFacts{identity.name + "-link", crc_framed, {}});
    core->start(now);
  }
  void send(std::uint64_t first, std::uint64_t last) {
    for (std::uint64_t n = first; n <= last; ++n) to_send.push_back(n);
  }

  SessionOptions options;
  SessionIdentity identity;
  SessionCounters counters;
  SessionLogMemory log;
  BindCountingShell shell;
  PeerStream stream;
  std::optional<SessionCore> core;
  std::deque<std::uint64_t> to_send;
  std::vector<std::uint64_t> received;
  int ups = 0, downs = 0;
};

class SessionAuthTest : public ::testing::Test {
 protected:
  // Edits what one write carries on its way (tamper, drop, reorder, inject); sees raw bytes.
  using Wire = std::function<void(std::vector<std::string>& messages)>;

  SessionAuthTest() {
    gateway.authenticate({{test_key(1)}, "gw", "surface"});
    surface.authenticate({{test_key(1)}, "surface", "gw"});
  }

  bool transfer(AuthEnd& from, AuthEnd& to, const Wire& wire) {
    if (from.shell.closed || to.shell.closed) return false;
    std::string out;
    from.core->fill(out, now);
    if (out.empty()) return false;
    std::vector<std::string> messages = split(out);
    (&from == &gateway ? sent_by_gateway : sent_by_surface)
        .insert((&from == &gateway ? sent_by_gateway : sent_by_surface).end(), messages.begin(),
                messages.end());
    if (wire) wire(messages);
    for (const std::string& m : messages) {
      if (!to.shell.closed) to.core->on_message(bytes_of(m), now);
    }
    return true;
  }
  void exchange() {
    for (int round = 0; round < 50; ++round) {
      const bool a = transfer(gateway, surface, to_surface);
      const bool b = transfer(surface, gateway, to_gateway);
      if (!a && !b) return;
    }
    FAIL() << "the cores never went quiet";
  }
  void advance(std::chrono::steady_clock::duration d) {
    const TimePoint end = now + d;
    for (;;) {
      AuthEnd* due = nullptr;
      for (AuthEnd* e : {&gateway, &surface}) {
        if (e->shell.closed) continue;
        if (!due || e->core->next_deadline() < due->core->next_deadline()) due = e;
      }
      if (!due || due->core->next_deadline() > end) break;
      now = std::max(now, due->core->next_deadline());
      due->core->on_tick(now, false);
      exchange();
    }
    now = end;
    exchange();
  }
  void connect(bool crc_framed = false) {
    sent_by_gateway.clear();
    sent_by_surface.clear();
    gateway.open_link(now, crc_framed);
    surface.open_link(now, crc_framed);
    exchange();
  }
  bool ready() const { return gateway.core->ready() && surface.core->ready(); }
  // Rewrites the AuthStep of a handshake message with `edit`.
  static void edit_step(std::string& message, const std::function<void(v1::AuthStep&)>& edit) {
    v1::Envelope e;
    ASSERT_TRUE(e.ParseFromString(message));
    ASSERT_TRUE(e.has_auth());
    edit(*e.mutable_auth());
    message = e.SerializeAsString();
  }
  // The last reliable payload the gateway sealed: counter | envelope | tag.
  static bool is_sealed(const std::string& m) { return m.size() > 20 && m[0] == 0; }

  TimePoint now = TimePoint{} + 1h;
  AuthEnd gateway{"gw", v1::Hello::ROLE_GATEWAY};
  AuthEnd surface{"surface", v1::Hello::ROLE_SURFACE};
  Wire to_surface;
  Wire to_gateway;
  std::vector<std::string> sent_by_gateway;
  std::vector<std::string> sent_by_surface;
};

// ------------------------------------------------------------------------------------ handshake

TEST_F(SessionAuthTest, ThreeStepsThenHellosAndEverythingSealed) {
  connect();
  ASSERT_TRUE(ready());
  EXPECT_EQ(gateway.core->authenticated_peer(), "surface");
  EXPECT_EQ(surface.core->authenticated_peer(), "gw");
  EXPECT_EQ(gateway.counters.auth_established, 1u);
  EXPECT_EQ(surface.counters.auth_established, 1u);
  EXPECT_EQ(surface.shell.binds, 1);
  // Gateway challenge; surface challenge and proof; gateway proof: unsealed, and nothing else is.
  ASSERT_GE(sent_by_gateway.size(), 3u);
  v1::Envelope first;
  ASSERT_TRUE(first.ParseFromString(sent_by_gateway[0]));
  EXPECT_TRUE(first.has_auth() && first.auth().proof().empty() &&
              !first.auth().challenge().empty());
  v1::Envelope answer;
  ASSERT_TRUE(answer.ParseFromString(sent_by_surface[0]));
  EXPECT_TRUE(answer.has_auth() && !answer.auth().proof().empty());
  v1::Envelope last;
  ASSERT_TRUE(last.ParseFromString(sent_by_gateway[1]));
  EXPECT_TRUE(last.has_auth() && last.auth().challenge().empty());
  gateway.send(1, 20);
  surface.send(100, 110);
  exchange();
  EXPECT_EQ(surface.received, range(1, 20));
  EXPECT_EQ(gateway.received, range(100, 110));
  for (std::size_t i = 2; i < sent_by_gateway.size(); ++i)
    EXPECT_TRUE(is_sealed(sent_by_gateway[i]));
  for (std::size_t i = 1; i < sent_by_surface.size(); ++i)
    EXPECT_TRUE(is_sealed(sent_by_surface[i]));
}

TEST_F(SessionAuthTest, LostChallengeIsSentAgain) {
  int lost = 0;
  to_surface = [&](std::vector<std::string>& m) {
    if (lost++ == 0) m.clear();
  };
  connect();
  EXPECT_FALSE(ready());
  advance(150ms);
  EXPECT_TRUE(ready());
}

TEST_F(SessionAuthTest, SurfaceWithoutTheGatewaysKeyRefusesAndBindsNothing) {
  surface.authenticate({{test_key(9)}, "surface", "gw"});
  gateway.send(1, 5);
  connect();
  EXPECT_FALSE(gateway.core->ready() || surface.core->ready());
  EXPECT_EQ(surface.counters.auth_failed_unknown_key, 1u);
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_TRUE(surface.received.empty());
  EXPECT_EQ(gateway.shell.closed, make_error_code(errc::refused_by_peer));
  EXPECT_TRUE(gateway.core->authenticated_peer().empty());
  // The refusal says nothing but "refused".
  v1::Envelope refusal;
  ASSERT_TRUE(refusal.ParseFromString(sent_by_surface.back()));
  EXPECT_EQ(refusal.refusal().detail(), "refused");
}

TEST_F(SessionAuthTest, GatewayRefusesASurfaceWhoseProofIsWrong) {
  to_gateway = [](std::vector<std::string>& m) {
    for (auto& message : m) {
      edit_step(message, [](v1::AuthStep& s) { s.mutable_proof()->at(3) ^= 1; });
    }
  };
  gateway.send(1, 5);
  connect();
  EXPECT_EQ(gateway.counters.auth_failed_bad_proof, 1u);
  EXPECT_EQ(surface.shell.closed, make_error_code(errc::refused_by_peer));
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_EQ(gateway.ups + surface.ups, 0);
  EXPECT_TRUE(surface.received.empty());
}

TEST_F(SessionAuthTest, SurfaceRefusesAGatewayWhoseProofIsWrongAndNeverBinds) {
  int writes = 0;
  to_surface = [&](std::vector<std::string>& m) {
    // The gateway's second write: its proof, then its sealed hello and data.
    if (++writes == 2) edit_step(m.front(), [](v1::AuthStep& s) { s.mutable_proof()->at(0) ^= 1; });
  };
  gateway.send(1, 5);
  connect();
  EXPECT_EQ(surface.counters.auth_failed_bad_proof, 1u);
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_TRUE(surface.received.empty());
  EXPECT_TRUE(surface.core->authenticated_peer().empty());
  EXPECT_EQ(gateway.shell.closed, make_error_code(errc::refused_by_peer));
}

TEST_F(SessionAuthTest, GatewayRefusesASurfaceWithAnotherIdentity) {
  surface.authenticate({{test_key(1)}, "impostor", "gw"});
  connect();
  EXPECT_EQ(gateway.counters.auth_failed_bad_proof, 1u);
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_EQ(surface.shell.closed, make_error_code(errc::refused_by_peer));
}

TEST_F(SessionAuthTest, AGatewayWithoutAuthenticationIsRefused) {
  gateway.options.authenticator = nullptr;
  gateway.send(1, 5);
  connect();
  EXPECT_EQ(surface.counters.auth_failed_unauthenticated, 1u);
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_TRUE(surface.received.empty());
  EXPECT_EQ(gateway.shell.closed, make_error_code(errc::refused_by_peer));
}

TEST_F(SessionAuthTest, ASurfaceWithoutAuthenticationRefusesTheChallenge) {
  surface.options.authenticator = nullptr;
  connect();
  EXPECT_EQ(surface.counters.auth_failed_unauthenticated, 1u);
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_EQ(gateway.shell.closed, make_error_code(errc::refused_by_peer));
}

TEST_F(SessionAuthTest, UnauthenticatedDataOnASerialLineIsNeverDelivered) {
  surface.open_link(now, true);
  std::string out;
  append_payload_envelope(out, {.seq = 1}, bytes_of(number(7)));
  for (const std::string& m : split(out)) surface.core->on_message(bytes_of(m), now);
  EXPECT_TRUE(surface.received.empty());
  EXPECT_EQ(surface.shell.binds, 0);
  EXPECT_EQ(surface.counters.before_hello, 1u);
}

// ------------------------------------------------------------------------------ sealed envelopes

class SealedEnvelopeTest : public SessionAuthTest {
 protected:
  // Ready, then the gateway's data towards the surface with `wire` in the way, then the line
  // clean again until the reliable stream has recovered.
  void send_through(const Wire& wire) {
    connect(true);
    ASSERT_TRUE(ready());
    to_surface = wire;
    gateway.send(1, 10);
    exchange();
    to_surface = nullptr;
    gateway.send(11, 20);
    advance(2s);
    EXPECT_EQ(surface.received, range(1, 20));  // exactly once, in order
    EXPECT_TRUE(ready());
  }
};

TEST_F(SealedEnvelopeTest, ABitFlippedAnywhereIsRejectedAsABadTag) {
  for (const std::size_t where : {0ul, 4ul, 10ul}) {
    surface.counters = {};
    surface.received.clear();
    bool done = false;
    send_through([&](std::vector<std::string>& m) {
      for (auto& message : m) {
        if (!done && is_sealed(message) && message.size() > where + 20) {
          message[where == 0 ? 3 : where] ^= 0x10;  // counter's low byte, envelope, ...
          done = true;
        }
      }
    });
    EXPECT_EQ(surface.counters.rejected_bad_tag, 1u) << where;
    EXPECT_EQ(surface.counters.rejected_replay + surface.counters.rejected_truncated, 0u);
    gateway.core->on_link_closed(true, "next");
    surface.core->on_link_closed(true, "next");
  }
}

TEST_F(SealedEnvelopeTest, AReplayedEnvelopeIsRejectedAsAReplay) {
  bool replayed = false;
  send_through([&](std::vector<std::string>& m) {
    if (!replayed && m.size() >= 2) {
      m.push_back(m.front());  // an earlier sealed message again, after newer ones
      replayed = true;
    }
  });
  ASSERT_TRUE(replayed);
  EXPECT_EQ(surface.counters.rejected_replay, 1u);
  EXPECT_EQ(surface.counters.rejected_bad_tag, 0u);
}

TEST_F(SealedEnvelopeTest, ATruncatedEnvelopeIsRejected) {
  int n = 0;
  send_through([&](std::vector<std::string>& m) {
    for (auto& message : m) {
      if (n == 0) message.resize(10);                  // shorter than counter and tag
      if (n == 1) message.resize(message.size() - 1);  // a byte of its tag missing
      ++n;
    }
  });
  EXPECT_EQ(surface.counters.rejected_truncated, 1u);
  EXPECT_EQ(surface.counters.rejected_bad_tag, 1u);
}

TEST_F(SealedEnvelopeTest, AReorderedEnvelopeIsRejectedAndResent) {
  bool swapped = false;
  send_through([&](std::vector<std::string>& m) {
    if (!swapped && m.size() >= 2) {
      std::swap(m[0], m[1]);
      swapped = true;
    }
  });
  ASSERT_TRUE(swapped);
  EXPECT_EQ(surface.counters.rejected_replay, 1u);
}

TEST_F(SealedEnvelopeTest, AnUnsealedEnvelopeAfterTheHandshakeIsNotDelivered) {
  connect(true);
  ASSERT_TRUE(ready());
  std::string out;
  append_payload_envelope(out, {.seq = 1}, bytes_of(number(666) + std::string(32, 'x')));
  for (const std::string& m : split(out)) surface.core->on_message(bytes_of(m), now);
  EXPECT_TRUE(surface.received.empty());
  EXPECT_EQ(surface.counters.rejected_bad_tag, 1u);
  EXPECT_TRUE(ready());
}

// ------------------------------------------------------------------------------- new links

TEST_F(SessionAuthTest, EveryLinkHandshakesAfreshAndOldSealedMessagesDoNotOpen) {
  connect();
  gateway.send(1, 5);
  exchange();
  const std::vector<std::string> old_link = sent_by_gateway;
  connect();
  ASSERT_TRUE(ready());
  EXPECT_EQ(surface.counters.auth_established, 2u);
  for (const std::string& m : old_link) {
    if (is_sealed(m)) surface.core->on_message(bytes_of(m), now);
  }
  EXPECT_GE(surface.counters.rejected_bad_tag, 1u);  // other keys on this link
  gateway.send(6, 10);
  exchange();
  EXPECT_EQ(surface.received, range(1, 10));
}

TEST_F(SessionAuthTest, ASurfaceThatReopensItsEndMakesTheGatewayStartOver) {
  connect(true);
  ASSERT_TRUE(ready());
  gateway.send(1, 5);
  exchange();
  // The surface reopens its serial port; the gateway, on its old link, sends data sealed with
  // the old keys: the surface asks for a new start, the gateway closes that link.
  surface.open_link(now, true);
  gateway.send(6, 8);
  exchange();
  EXPECT_EQ(gateway.counters.auth_restarts, 1u);
  EXPECT_EQ(gateway.shell.closed, make_error_code(errc::closed));
  EXPECT_GE(surface.counters.before_hello, 1u);
  gateway.open_link(now, true);  // its serial client reopens
  advance(1s);
  ASSERT_TRUE(ready());
  EXPECT_EQ(surface.received, range(1, 8));
}

// The fuzz target's invariants (tests/fuzz/session_auth_fuzz.cpp) on seeded random inputs: an
// attacker's bytes, replays, flips and cuts before and after the handshake.
TEST(SessionAuthFuzz, RandomInputsKeepTheInvariants) {
  for (std::uint32_t seed = 1; seed <= 200; ++seed) {
    std::mt19937 rng(seed);
    std::vector<std::uint8_t> input(1 + rng() % 300);
    for (auto& b : input) b = static_cast<std::uint8_t>(rng());
    EXPECT_EQ(LLVMFuzzerTestOneInput(input.data(), input.size()), 0);
  }
}

}  // namespace
}  // namespace canbridge::backbone
