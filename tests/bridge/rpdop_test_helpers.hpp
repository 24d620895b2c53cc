// Test vocabulary shared by the RPDOP sender and relay tests: readable failure output for frames
// and outcomes, and packets and fragments built the way the PDOP codec cuts them.
#pragma once

#include <chrono>
#include <cstdint>
#include <numeric>
#include <ostream>
#include <vector>

#include "can/frame.hpp"
#include "canopen/pdop.hpp"
#include "routing/pdop_segmenter.hpp"

namespace canbridge::can {
inline void PrintTo(const Frame& frame, std::ostream* os) {
  *os << to_string(frame);
}
}  // namespace canbridge::can

namespace canbridge::bridge {
inline void PrintTo(PdopResult result, std::ostream* os) {
  *os << to_string(result);
}
inline void PrintTo(const PdopOutcome& outcome, std::ostream* os) {
  *os << to_string(outcome);
}
}  // namespace canbridge::bridge

namespace canbridge::bridge::rpdop_test {

using Bytes = std::vector<std::uint8_t>;
using Frames = std::vector<can::Frame>;

// A start far from the clock's epoch, so that times before it stay valid.
inline const PdopSegmenter::TimePoint t0 = PdopSegmenter::TimePoint{} + std::chrono::seconds(1000);

// 0, 1, 2, ... so a misplaced byte shows in a failure.
inline Bytes counting(std::size_t size, std::uint8_t first = 0) {
  Bytes bytes(size);
  std::iota(bytes.begin(), bytes.end(), first);
  return bytes;
}
// The fragments of `bytes` to `node`'s RPDO `rpdo`, as the codec cuts them.
inline Frames fragments(NodeId node, unsigned rpdo, const Bytes& bytes) {
  return canopen::pdop::fragment(canopen::pdop::rpdo_base(rpdo), node, bytes);
}
inline can::Frame abort_of(NodeId node, unsigned rpdo) {
  return canopen::pdop::abort_frame(canopen::pdop::rpdo_base(rpdo), node);
}

}  // namespace canbridge::bridge::rpdop_test
