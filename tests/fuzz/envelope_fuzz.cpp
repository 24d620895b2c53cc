// libFuzzer target: one backbone message as it leaves the link framing: a canbridge.v1.Envelope,
// its Payload and the FrameBatch inside, decoded to CAN frames (see envelope_pipeline.hpp for
// the invariants).
#include <cstddef>
#include <cstdint>
#include <span>

#include "tests/fuzz/envelope_pipeline.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  canbridge::fuzz::process_envelope({data, size});
  return 0;
}
