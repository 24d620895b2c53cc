// What the bridge does with one backbone message once a link has framed it (envelope -> payload
// -> FrameBatch -> CAN frames), with the invariants each step must keep, shared by the fuzz
// targets.
#pragma once

#include <cstdint>
#include <span>

namespace canbridge::fuzz {

// Aborts (so libFuzzer records the input) when an invariant does not hold. Unlike assert() it
// stays active in optimised builds.
void require(bool holds, const char* invariant);

// Parses `message` as a canbridge.v1.Envelope and, when it carries a payload, the payload as a
// canbridge.v1.Payload and its FrameBatch as CAN frames. Garbage must be refused, never crash;
// a FrameBatch that decodes (plain or with head runs) must survive re-encoding with
// FrameBatchBuilder in either form unchanged.
void process_envelope(std::span<const std::uint8_t> message);

}  // namespace canbridge::fuzz
