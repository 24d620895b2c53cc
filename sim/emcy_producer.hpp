// The emergency (EMCY) producer of a simulated CANopen node: error register 1001h, error history
// 1003h, COB-ID 1014h and inhibit time 1015h, and the EMCY frames (CiA 301 7.2.7). A pure core:
// the time in, frames out.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <span>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "sim/node_spec.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

class EmcyProducer {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  using ManufacturerField = std::array<std::uint8_t, 5>;

  static constexpr std::uint16_t kErrorRegister = 0x1001;
  static constexpr std::uint16_t kErrorHistory = 0x1003;
  static constexpr std::uint16_t kCobId = 0x1014;
  static constexpr std::uint16_t kInhibitTime = 0x1015;
  static constexpr std::size_t kHistoryDepth = 8;      // 1003h subs 1..8
  static constexpr std::size_t kQueueDepth = 8;        // EMCYs waiting for the inhibit time
  static constexpr std::uint8_t kGenericError = 0x01;  // 1001h bit 0

  // Adds 1014h (COB-ID EMCY u32 = 80h + node, rw, bit 31 = no EMCY), 1015h (inhibit time u16 in
  // 100 us, rw, from spec), 1003h (sub 0 u8 rw = number of errors, writing 0 clears the history;
  // subs 1..8 u32 ro, newest at sub 1, each = error code | (mfr[0] | mfr[1] << 8) << 16, i.e. the
  // first two bytes of the EMCY's manufacturer-specific field as the additional information), and
  // 1001h (u8 ro) unless the node added it already. Enabled from the start.
  EmcyProducer(ObjectDictionary& od, canopen::NodeId node, const EmcySpec& spec);

  // 1014h follows the node id when it holds the default 80h + node (in its current and its reset
  // value separately); bit 31 is kept.
  void set_node_id(canopen::NodeId node);
  // False while stopped or initialising: raised errors still change 1001h and 1003h but no EMCY is
  // sent or queued; the queue is discarded.
  void set_enabled(bool on);

  // An error occurred: ORs register_bits into 1001h (bit 0, generic error, always with a code other
  // than 0000h), records the code in 1003h and sends [code lo, code hi, 1001h, mfr0..mfr4] on the
  // COB-ID in 1014h (nothing if its bit 31 is set). During the inhibit time (1015h) the EMCY is
  // queued (FIFO of kQueueDepth; the frame keeps the 1001h value of the moment it was raised;
  // overflow is counted as dropped) and goes out when the inhibit time ends.
  void raise(std::uint16_t code, std::uint8_t register_bits, const ManufacturerField& mfr,
             TimePoint now, std::vector<can::Frame>& out);
  // An error went away: clears register_bits in 1001h, and bit 0 too unless another error is still
  // indicated (another register bit, or a generic-only error raised since the last reset_errors),
  // then sends `code` (CiA 301: 0000h; the qd scheme sends its new Fxxxh pattern) with the new
  // 1001h. Not recorded in 1003h.
  void clear_error(std::uint16_t code, std::uint8_t register_bits, const ManufacturerField& mfr,
                   TimePoint now, std::vector<can::Frame>& out);
  // All errors gone: 1001h = 0 and an EMCY with code 0000h (error reset). 1003h keeps its history.
  void reset_errors(TimePoint now, std::vector<can::Frame>& out);
  // NMT reset: the queue and the inhibit time are forgotten (the node restores the objects).
  void reset();

  // Sends queued EMCYs whose inhibit time has ended.
  void poll(TimePoint now, std::vector<can::Frame>& out);
  // When poll() next has something to do; TimePoint::max() when nothing is queued.
  TimePoint next_deadline() const;

  // Refuses, with 0x06090030 (value range): 1003h sub 0 other than 0; a 1014h with bits 11..30 set,
  // or a CAN-ID change while the EMCY is and stays valid (bit 31 = 0).
  std::error_code check_write(const OdEntry& entry, std::span<const std::uint8_t> data) const;
  // 1003h sub 0 = 0 clears the history.
  void on_written(const OdEntry& entry, TimePoint now, std::vector<can::Frame>& out);

  struct Counters {
    std::uint64_t sent = 0;
    std::uint64_t queued = 0;
    std::uint64_t dropped = 0;
  };
  const Counters& counters() const { return counters_; }

 private:
  std::uint8_t error_register() const;
  void set_error_register(std::uint8_t value);
  void record(std::uint32_t history_entry);
  void emit(can::Frame frame, TimePoint now, std::vector<can::Frame>& out);
  void transmit(can::Frame frame, TimePoint now, std::vector<can::Frame>& out);

  ObjectDictionary& od_;
  canopen::NodeId node_;
  bool enabled_ = true;
  // Some error set only the generic bit, so bit 0 stays when other bits are cleared.
  bool generic_error_active_ = false;
  std::deque<can::Frame> queue_;
  TimePoint inhibit_end_ = TimePoint::min();
  Counters counters_;
};

}  // namespace canbridge::sim
