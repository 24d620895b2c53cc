// libFuzzer target: an authenticating SessionCore (SessionOptions::authenticator) fed an
// attacker's bytes before and after its handshake, between an honest gateway's traffic. Also
// linked into backbone_session_core_tests, which feeds it seeded random inputs.
//
// Input: byte 0: bit 0: the attacker writes to the surface (else to the gateway); bit 1: the
// honest handshake completes first (else the attacker talks to a fresh core); bit 2: the line is
// a serial line (crc_framed). Then operations [op, arg, ...]:
//   op % 5 == 0: arg bytes that follow go to the attacked core as one message;
//             1: the honest ends exchange what they have (the gateway queues payload arg first);
//             2: time passes: arg ms, each core ticked;
//             3: an honest message seen on the wire (index arg) again, one byte (next input
//                byte) xored with the byte after (zero: replayed unchanged);
//             4: an honest message seen on the wire (index arg) cut to (next input byte) bytes.
//
// Invariants: without the handshake the attacked core binds nothing, delivers nothing and never
// becomes ready; what the surface delivers is always a prefix of what the honest gateway queued,
// in order, each once; an authenticated peer is the configured one or nobody.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/session_core.hpp"
#include "tests/fuzz/fuzz_input.hpp"

namespace {

using namespace canbridge::backbone;
namespace v1 = canbridge::v1;
using namespace std::chrono_literals;

using canbridge::fuzz::Input;
using canbridge::fuzz::require;

class Shell final : public SessionShell {
 public:
  void wake_writer() override {}
  void close_link(std::error_code) override { closed = true; }
  void pause_reading(bool) override {}
  BindResult bind(const v1::Hello&) override {
    ++binds;
    return {stream, v1::Refusal::PROTOCOL_ERROR, {}};
  }
  void carry(PeerStream&) override {}
  PeerStream* stream = nullptr;
  int binds = 0;
  bool closed = false;
};

struct FuzzedEnd {
  FuzzedEnd(bool gateway, bool crc_framed, SessionCore::TimePoint now)
      : stream(options(gateway), handlers()) {
    identity.role = gateway ? v1::Hello::ROLE_GATEWAY : v1::Hello::ROLE_SURFACE;
    identity.expected_peer = gateway ? v1::Hello::ROLE_SURFACE : v1::Hello::ROLE_GATEWAY;
    identity.name = gateway ? "gw" : "surface";
    identity.session_id = gateway ? 1 : 2;
    shell.stream = &stream;
    core.emplace(identity, options(gateway), gateway ? &stream : nullptr, counters, log, shell,
                 SessionCore::LinkFacts{identity.name, crc_framed, {}});
    core->start(now);
  }
  static SessionOptions options(bool gateway) {
    SessionOptions o;
    o.keepalive_interval = 100ms;
    o.dead_after = 1000ms;
    o.retransmit_timeout = 400ms;
    o.resend_buffer_messages = 64;
    o.resend_buffer_bytes = 16 * 1024;
    o.authenticator = [gateway](const std::string&) {
      PeerAuthenticatorOptions a;
      a.role = gateway ? AuthRole::gateway : AuthRole::surface;
      a.own_identity = gateway ? "gw" : "surface";
      a.peer_identity = gateway ? "surface" : "gw";
      std::array<std::uint8_t, kPreSharedKeySize> key{};
      key.fill(0x5a);
      a.keys.emplace_back(key);
      return std::make_unique<PeerAuthenticator>(std::move(a));
    };
    return o;
  }
  PeerStream::Handlers handlers() {
    return {[this](PayloadSink& sink) {
              while (!to_send.empty() && sink.room() > 0 && sink.reliable_room(8)) {
                std::string p(8, '\0');
                std::memcpy(p.data(), &to_send.front(), 8);
                sink.send_reliable(std::move(p));
                to_send.pop_front();
              }
            },
            [this](std::span<const std::uint8_t> p, bool reliable) {
              std::uint64_t n = 0;
              std::memcpy(&n, p.data(), std::min<std::size_t>(8, p.size()));
              received.push_back({n, reliable, p.size()});
            },
            nullptr, nullptr};
  }

  struct Delivery {
    std::uint64_t n;
    bool reliable;
    std::size_t size;
  };
  SessionIdentity identity;
  SessionCounters counters;
  SessionLogMemory log;
  Shell shell;
  PeerStream stream;
  std::optional<SessionCore> core;
  std::deque<std::uint64_t> to_send;
  std::vector<Delivery> received;
};

struct World {
  World(bool crc_framed) : gateway(true, crc_framed, now), surface(false, crc_framed, now) {}

  void transfer(FuzzedEnd& from, FuzzedEnd& to) {
    if (from.shell.closed || to.shell.closed) return;
    std::string out;
    from.core->fill(out, now);
    DelimitedDecoder decoder;
    decoder.feed({reinterpret_cast<const std::uint8_t*>(out.data()), out.size()},
                 [&](std::span<const std::uint8_t> m) {
                   if (wire.size() < 256) wire.emplace_back(m.begin(), m.end());
                   if (!to.shell.closed) to.core->on_message(m, now);
                 });
  }
  void exchange() {
    for (int i = 0; i < 8; ++i) {
      transfer(gateway, surface);
      transfer(surface, gateway);
    }
  }
  void tick(std::chrono::milliseconds d) {
    now += d;
    for (FuzzedEnd* e : {&gateway, &surface}) {
      if (!e->shell.closed) e->core->on_tick(now, false);
    }
    exchange();
  }

  SessionCore::TimePoint now = SessionCore::TimePoint{} + 1h;
  FuzzedEnd gateway;
  FuzzedEnd surface;
  std::vector<std::vector<std::uint8_t>> wire;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  Input in({data, size});
  const std::uint8_t mode = in.byte();
  const bool attack_surface = mode & 1;
  const bool honest_first = mode & 2;
  World world((mode & 4) != 0);
  FuzzedEnd& target = attack_surface ? world.surface : world.gateway;
  if (honest_first) world.exchange();
  std::uint64_t queued = 0;

  for (int ops = 0; !in.empty() && ops < 64; ++ops) {
    const std::uint8_t op = in.byte();
    const std::uint8_t arg = in.byte();
    switch (op % 5) {
      case 0: {
        const auto bytes = in.take(arg);
        if (!target.shell.closed) target.core->on_message(bytes, world.now);
        break;
      }
      case 1:
        if (honest_first) {
          world.gateway.to_send.push_back(++queued);
          world.exchange();
        }
        break;
      case 2:
        if (honest_first) world.tick(std::chrono::milliseconds(arg));
        break;
      case 3:
      case 4: {
        if (world.wire.empty()) break;
        std::vector<std::uint8_t> m = world.wire[arg % world.wire.size()];
        const std::uint8_t at = in.byte();
        const std::uint8_t value = in.byte();
        if (op % 5 == 3 && !m.empty()) m[at % m.size()] ^= value;
        if (op % 5 == 4) m.resize(std::min<std::size_t>(m.size(), at));
        if (!target.shell.closed) target.core->on_message(m, world.now);
        break;
      }
    }
    if (!honest_first) {
      require(!target.core->ready(), "an unproven peer made a core ready");
      require(target.shell.binds == 0, "an unproven peer was bound");
      require(target.received.empty(), "an unproven peer's payload was delivered");
      require(target.core->authenticated_peer().empty(), "an unproven peer is authenticated");
    }
  }
  // Whatever the attacker did, the surface delivered the honest gateway's payloads: a prefix of
  // 1, 2, ... in order, each once, and nothing else.
  for (std::size_t i = 0; i < world.surface.received.size(); ++i) {
    const auto& d = world.surface.received[i];
    require(d.reliable && d.size == 8 && d.n == i + 1, "the surface delivered a forged payload");
  }
  require(world.gateway.received.empty(), "the gateway delivered a forged payload");
  for (FuzzedEnd* e : {&world.gateway, &world.surface}) {
    const std::string& peer = e->core->authenticated_peer();
    require(peer.empty() || peer == (e == &world.gateway ? "surface" : "gw"),
            "an authenticated peer that is not the configured one");
  }
  return 0;
}
