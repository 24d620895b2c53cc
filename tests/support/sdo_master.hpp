// A CANopen SDO client (the master's side of CiA 301 SDO) for system tests, on a raw SocketCAN
// socket and deliberately independent of the project's own SDO code: expedited, segmented and
// block transfers (with CRC), each step blocking until the server's answer arrives or a deadline
// passes (poll(2) underneath, never a sleep). Frames on the socket other than the addressed
// node's SDO responses (heartbeats, PDOs, other nodes) are skipped.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "can/frame.hpp"
#include "tests/support/raw_can.hpp"

namespace canbridge::test {

// How one transfer ended.
struct SdoOutcome {
  std::vector<std::uint8_t> data;      // uploads: the value read
  std::optional<std::uint32_t> abort;  // the server's abort code, if it aborted
  std::string failure;                 // timeout or protocol violation, described; else empty
  std::chrono::milliseconds elapsed{0};
  bool ok() const { return !abort && failure.empty(); }
  bool aborted_with(std::uint32_t code) const { return abort && *abort == code; }
};
// "ok (N bytes)", "abort 0x06020000", "failure: ..." for assertion messages.
std::string describe(const SdoOutcome& outcome);

// CRC-16 of SDO block transfers (CRC-16/XMODEM), written out here so the check does not reuse
// the code under test.
std::uint16_t sdo_block_crc(std::span<const std::uint8_t> data);

class SdoMaster {
 public:
  struct Options {
    std::chrono::milliseconds timeout{2000};  // longest wait for each answer of the server
    std::uint8_t block_size = 127;            // sub-block size offered in block uploads
    bool crc = true;                          // ask for the CRC in block transfers
  };

  explicit SdoMaster(RawCanSocket& socket) : SdoMaster(socket, Options{}) {}
  SdoMaster(RawCanSocket& socket, Options options) : socket_(socket), options_(options) {}

  // Initiate upload; expedited or segmented, as the server answers.
  SdoOutcome upload(std::uint8_t node, std::uint16_t index, std::uint8_t sub);
  // Expedited for 1..4 bytes, segmented for more (or for none).
  SdoOutcome download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                      std::span<const std::uint8_t> data);
  // Segmented even for 1..4 bytes (to check that a server refuses it).
  SdoOutcome segmented_download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                                std::span<const std::uint8_t> data);
  SdoOutcome block_download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                            std::span<const std::uint8_t> data);
  SdoOutcome block_upload(std::uint8_t node, std::uint16_t index, std::uint8_t sub);

  // A 1..4-byte value read by upload(), little-endian; nullopt (with `outcome` set) otherwise.
  std::optional<std::uint32_t> read_u32(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                                        SdoOutcome* outcome = nullptr);

  // Frames on 0x580+node that matched no step of a transfer (late answers, strays).
  std::size_t skipped_responses() const { return skipped_responses_; }

 private:
  using Clock = std::chrono::steady_clock;
  // Sends `request` to node (0x600+node).
  void send(std::uint8_t node, const can::Frame& request);
  // The next frame on 0x580+node within the per-answer timeout; nullopt on timeout.
  std::optional<can::Frame> next_response(std::uint8_t node);
  // Waits for the answer to an initiate request for `index`:`sub`: skips responses naming
  // another object; an abort for this object ends the transfer (returns false, `out` set).
  std::optional<can::Frame> initiate_answer(std::uint8_t node, std::uint16_t index,
                                            std::uint8_t sub, SdoOutcome& out);
  // Handles an answer inside a transfer: abort (false, outcome set) or the frame to check.
  bool is_abort(const can::Frame& answer, SdoOutcome& out);
  // Records a failure (timeout, protocol violation) and sends the server an abort with `code`
  // so that it does not stay inside the transfer.
  void fail(std::uint8_t node, std::uint16_t index, std::uint8_t sub, SdoOutcome& out,
            const std::string& why, std::uint32_t code);

  RawCanSocket& socket_;
  Options options_;
  std::size_t skipped_responses_ = 0;
};

}  // namespace canbridge::test
