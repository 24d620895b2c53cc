// A stand-in for the session's PayloadSink: one write after another with a fixed room each,
// recording every payload handed over, so producers (outbox, role cores) are tested without a link.
#pragma once

#include <chrono>
#include <cstddef>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "backbone/peer_stream.hpp"

namespace canbridge::test {

// Bytes the session adds around one payload in a write: length prefix, seq, ack, payload tag and
// length (session.cpp append_envelope), generously for small sequence numbers.
inline constexpr std::size_t kEnvelopeBytes = 12;

// Stands in for one SessionLink write after another: each produce() call is one write with
// `room_per_write` bytes; records every payload in the order it was handed over.
class FakeSink final : public backbone::PayloadSink {
 public:
  using Clock = std::chrono::steady_clock;
  struct Sent {
    std::string bytes;
    bool reliable;
    std::size_t room_before;  // room() when the payload was handed over
  };

  explicit FakeSink(std::size_t room_per_write = 16 * 1024) : room_per_write_(room_per_write) {}

  // Starts the next write (the real session calls produce() once per write).
  void next_write() { used_ = 0; }

  std::size_t room() const override {
    return used_ >= room_per_write_ ? 0 : room_per_write_ - used_;
  }
  bool reliable_room(std::size_t) const override { return reliable_room_; }
  void send_reliable(std::string payload) override {
    if (!reliable_room_) ++reliable_calls_while_full_;  // the outbox should have asked first
    record(std::move(payload), true);
  }
  void send_reliable_since(std::string payload, Clock::time_point born) override {
    borns.push_back(born);
    send_reliable(std::move(payload));
  }
  Clock::time_point now() const override { return now_; }
  void send_unreliable(std::span<const std::uint8_t> payload) override {
    record({reinterpret_cast<const char*>(payload.data()), payload.size()}, false);
  }

  std::vector<Sent> sent;
  std::vector<Clock::time_point> borns;  // of the reliable payloads, in order
  Clock::time_point now_ = Clock::time_point{} + std::chrono::hours(1);
  bool reliable_room_ = true;
  std::size_t reliable_calls_while_full_ = 0;

 private:
  void record(std::string payload, bool reliable) {
    const std::size_t before = room();
    used_ += payload.size() + kEnvelopeBytes;
    sent.push_back({std::move(payload), reliable, before});
  }

  std::size_t room_per_write_;
  std::size_t used_ = 0;
};

}  // namespace canbridge::test
