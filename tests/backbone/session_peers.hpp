// Two ends of a backbone session in one process, for tests: a "gateway" end with one preset
// stream and a "surface" end that binds streams by the peer's hello, each recording what its
// stream delivers and producing numbered reliable payloads on demand.
#pragma once

#include <algorithm>
#include <boost/asio/io_context.hpp>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "backbone/session.hpp"

namespace canbridge::backbone::testing {

// One end: a stream whose producer sends the numbers next_..limit_ as 8-byte reliable payloads
// (little endian), and whose receiver records every payload it gets.
// Short intervals, so the session tests that wait for keepalives, dead links and resends are fast.
inline SessionOptions fast_options() {
  using namespace std::chrono_literals;
  SessionOptions o;
  o.keepalive_interval = 50ms;
  o.dead_after = 300ms;
  o.retransmit_timeout = 200ms;
  o.resend_buffer_messages = 512;
  o.resend_buffer_bytes = 64 * 1024;
  return o;
}

class SessionEnd {
 public:
  SessionEnd(std::string name, v1::Hello::Role role, SessionOptions options,
             std::vector<std::uint32_t> modules = {})
      : options_(options),
        stream_(options_,
                PeerStream::Handlers{[this](PayloadSink& sink) { produce(sink); },
                                     [this](std::span<const std::uint8_t> p, bool reliable) {
                                       receive(p, reliable);
                                     },
                                     [this](const v1::Hello&) { ++ups; }, [this] { ++downs; },
                                     [this](const v1::Hello&) { ++peer_restarts; },
                                     [this](const std::string& p, ReliableDrop why) {
                                       dropped.push_back({number(bytes_of(p)), why});
                                     }}) {
    identity_.role = role;
    identity_.expected_peer =
        role == v1::Hello::ROLE_GATEWAY ? v1::Hello::ROLE_SURFACE : v1::Hello::ROLE_GATEWAY;
    identity_.name = std::move(name);
    identity_.module_ids = std::move(modules);
    identity_.session_id = random_session_id();
  }

  // Attaches a link: the gateway end presets its stream, the surface end binds on the hello.
  std::shared_ptr<SessionLink> attach(std::shared_ptr<MessageLink> link) {
    const bool preset = identity_.role == v1::Hello::ROLE_GATEWAY;
    auto session =
        SessionLink::create(std::move(link), identity_, options_, preset ? &stream_ : nullptr,
                            preset ? SessionLink::Binder{}
                                   : SessionLink::Binder([this](const v1::Hello&, SessionLink&) {
                                       return BindResult{&stream_, {}, {}};
                                     }),
                            counters);
    session->start();
    links.push_back(session);
    return session;
  }

  // Sends unreliable payloads numbered up to `last` (inclusive), each once: lost ones stay lost.
  void send_unreliable_up_to(std::uint64_t last) {
    unreliable_limit_ = last;
    stream_.wake();
  }

  // Queues reliable payloads numbered up to `last` (inclusive).
  void send_up_to(std::uint64_t last) {
    limit_ = last;
    stream_.wake();
  }

  static std::span<const std::uint8_t> bytes_of(const std::string& s) {
    return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
  }
  static std::uint64_t number(std::span<const std::uint8_t> p) {
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < p.size() && i < 8; ++i) v |= std::uint64_t{p[i]} << (8 * i);
    return v;
  }

  PeerStream& stream() { return stream_; }
  SessionLink::Identity& identity() { return identity_; }

  SessionCounters counters;
  std::vector<std::uint64_t> received;  // reliable payload numbers, in delivery order
  std::uint64_t unreliable = 0;
  std::uint64_t highest_unreliable = 0;  // the highest unreliable payload number received
  std::uint64_t corrupt = 0;             // payloads of the wrong size
  int ups = 0;
  int downs = 0;
  int peer_restarts = 0;
  // Reliable payloads this end gave up (PeerStream::Handlers::on_reliable_dropped): their numbers.
  struct Dropped {
    std::uint64_t number;
    ReliableDrop why;
  };
  std::vector<Dropped> dropped;
  // Called after each reliable payload this end received (its number), e.g. to cut right there.
  std::function<void(std::uint64_t)> after_receive;
  std::size_t payload_size = 8;
  std::vector<std::shared_ptr<SessionLink>> links;

 private:
  void produce(PayloadSink& sink) {
    while (next_ <= limit_ && sink.room() > payload_size + 16 && sink.reliable_room(payload_size)) {
      std::string p(payload_size, '\0');
      for (std::size_t i = 0; i < 8 && i < payload_size; ++i) {
        p[i] = static_cast<char>((next_ >> (8 * i)) & 0xFF);
      }
      // The rest of the payload repeats a pattern derived from the number: corruption shows.
      for (std::size_t i = 8; i < payload_size; ++i) p[i] = static_cast<char>(next_ * 31 + i);
      sink.send_reliable(std::move(p));
      ++next_;
    }
    while (next_unreliable_ <= unreliable_limit_ && sink.room() > payload_size + 16) {
      std::string p(payload_size, '\0');
      for (std::size_t i = 0; i < 8 && i < payload_size; ++i) {
        p[i] = static_cast<char>((next_unreliable_ >> (8 * i)) & 0xFF);
      }
      sink.send_unreliable({reinterpret_cast<const std::uint8_t*>(p.data()), p.size()});
      ++next_unreliable_;
    }
  }
  void receive(std::span<const std::uint8_t> p, bool reliable) {
    if (!reliable) {
      ++unreliable;
      highest_unreliable = std::max(highest_unreliable, number(p));
      return;
    }
    if (p.size() != payload_size) {
      ++corrupt;
      return;
    }
    const std::uint64_t n = number(p);
    for (std::size_t i = 8; i < payload_size; ++i) {
      if (p[i] != static_cast<std::uint8_t>(n * 31 + i)) {
        ++corrupt;
        return;
      }
    }
    received.push_back(n);
    if (after_receive) after_receive(n);
  }

  SessionOptions options_;
  SessionLink::Identity identity_;
  PeerStream stream_;
  std::uint64_t next_ = 1;
  std::uint64_t limit_ = 0;
  std::uint64_t next_unreliable_ = 1;
  std::uint64_t unreliable_limit_ = 0;
};

// True when `received` is exactly 1..n in order.
inline bool exactly_once_in_order(const std::vector<std::uint64_t>& received, std::uint64_t n) {
  if (received.size() != n) return false;
  for (std::uint64_t i = 0; i < n; ++i) {
    if (received[i] != i + 1) return false;
  }
  return true;
}

}  // namespace canbridge::backbone::testing
