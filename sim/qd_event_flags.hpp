// QD-CANopen subsystem state-change flags (seeds/003, "Enhancing the Role of the CANopen Emergency
// Object"): a change in subsystem s sets bit s of an Fxxxh EMCY error code, so a controller learns
// of it without polling; the Event Reset Register re-arms the flags and a hold-off time bounds the
// EMCY rate. A pure core on top of EmcyProducer.
#pragma once

#include <chrono>
#include <cstdint>
#include <span>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "sim/emcy_producer.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

class QdEventFlags {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;

  // UNSIGNED16 rw. Reading returns the current flags; writing clears the flags whose bits are set
  // in the written value (bits 12..15 are ignored).
  static constexpr std::uint16_t kEventResetRegister = 0x2F00;
  // UNSIGNED16 rw, milliseconds: minimum gap between two state-change EMCYs.
  static constexpr std::uint16_t kHoldoffTime = 0x2F01;
  static constexpr unsigned kSubsystems = 12;
  static constexpr std::uint16_t kCodeBase = 0xF000;
  // 1001h bit 7 (manufacturer-specific) marks "a state-change flag is set".
  static constexpr std::uint8_t kErrorRegisterBit = 0x80;

  // Adds the two objects (sub 0 each); the hold-off is clamped to 0..65535 ms.
  QdEventFlags(ObjectDictionary& od, EmcyProducer& emcy, std::chrono::milliseconds holdoff);

  // Subsystem 0..11 changed state. Its flag is set and the EMCY with the new code goes out, or at
  // the end of the hold-off. While the flag is already set the change is not announced (the
  // controller re-arms it by clearing). Out of range: ignored.
  void flag(unsigned subsystem, TimePoint now, std::vector<can::Frame>& out);
  std::uint16_t code() const { return static_cast<std::uint16_t>(kCodeBase | flags_); }
  std::uint16_t flags() const { return flags_; }

  // Sends the coalesced EMCY when the hold-off ends, with the code current then, and only if it
  // differs from the code last announced.
  void poll(TimePoint now, std::vector<can::Frame>& out);
  // When poll() next has something to do; TimePoint::max() when nothing waits.
  TimePoint next_deadline() const;

  // Both objects accept any value; present for the node's uniform write guard.
  std::error_code check_write(const OdEntry& entry, std::span<const std::uint8_t> data) const;
  // Event Reset Register written: the flags named are cleared and the new pattern announced. Not
  // 0000h as CiA 301 would have it: seeds/003 sends the new Fxxxh pattern, and when no flag is
  // left that is F000h, sent through EmcyProducer::clear_error so that 1001h bit 7 (and bit 0 if no
  // other error remains) is cleared.
  void on_written(const OdEntry& entry, TimePoint now, std::vector<can::Frame>& out);

  // NMT reset: flags cleared, nothing sent, the hold-off forgotten.
  void reset();

 private:
  std::chrono::milliseconds holdoff() const;
  TimePoint holdoff_end() const;
  void changed(TimePoint now, std::vector<can::Frame>& out);
  void announce(TimePoint now, std::vector<can::Frame>& out);

  ObjectDictionary& od_;
  EmcyProducer& emcy_;
  std::uint16_t flags_ = 0;
  std::uint16_t announced_code_ = kCodeBase;
  bool announced_once_ = false;
  TimePoint last_announcement_{};
  bool waiting_for_holdoff_ = false;
};

}  // namespace canbridge::sim
