// A firmware update of one node through its CiA 302 loader (stop the application, wait for the
// loader, block-download the image to 1F50h:01, verify 1F56h:01, start, wait for the application)
// as a pure sequencer: frames and an injected clock in, frames, progress and one result out.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_transfer.hpp"

namespace canbridge::canopen {

// CiA 302 program download objects and the loader's boot-up COB-ID (seeds/003: the loader
// announces itself on 0x720+N, the application on 0x700+N, so a master can tell them apart).
namespace firmware_objects {
inline constexpr std::uint16_t program_data = 0x1F50;            // :01 DOMAIN, the image
inline constexpr std::uint16_t program_control = 0x1F51;         // :01 0 stop, 1 start
inline constexpr std::uint16_t program_identification = 0x1F56;  // :01 CRC-32 of the program
inline constexpr std::uint16_t flash_status = 0x1F57;            // :01 0 valid, 1 none
inline constexpr std::uint16_t loader_boot_up = 0x720;           // + node id
}  // namespace firmware_objects

struct FirmwareDownloadOptions {
  // Longest wait for any one SDO answer. A loader erases flash while the image arrives and may
  // stay silent for seconds before it confirms a block: this is that wait, not the usual 1 s.
  std::chrono::milliseconds answer_timeout{std::chrono::seconds(20)};
  // Longest wait for each boot-up (the loader's after stop, the application's after start).
  std::chrono::milliseconds boot_timeout{std::chrono::seconds(10)};
  // Segments per block of the image's download; 0: segmented transfer.
  std::uint8_t block_size = 127;
};

// Where the node is when the update begins. `unknown` adds a probe: an upload of 1F57h:01
// (flash status), which only the loader serves (the application answers "no object").
enum class FirmwareStartMode : std::uint8_t { unknown, application, loader };

// The steps in order; `done` once the application's boot-up arrived. Names (to_string) are the
// ones the endpoint prints in PROGRESS lines and in the error text of a failed step.
enum class FirmwareStep : std::uint8_t {
  probe,             // read 1F57h:01: loader or application?
  stop,              // write 1F51h:01 = 0 (application -> loader)
  wait_loader,       // boot-up 0x720+N
  download,          // block download of the image to 1F50h:01
  verify,            // read 1F56h:01 and compare with the image's CRC-32 trailer
  start,             // write 1F51h:01 = 1
  wait_application,  // boot-up 0x700+N
  done,
};
const char* to_string(FirmwareStep step);

struct FirmwareProgress {
  FirmwareStep step = FirmwareStep::probe;
  std::size_t bytes_done = 0;   // image bytes the node acknowledged
  std::size_t bytes_total = 0;  // the image's size
};

struct FirmwareResult {
  // Empty on success. An SdoAbort: the abort of the failed step's SDO transfer (received or
  // decided locally, e.g. timeout 0x05040000), or 0x08000020 (cannot transfer) when no SDO abort
  // applies (a missing boot-up, a wrong identification, an unusable image), or abort()'s reason.
  std::error_code error;
  FirmwareStep step = FirmwareStep::probe;  // the step that failed (done on success)
  std::string detail;                       // why, for people: "no boot-up 0x720+5 in 10000 ms"
  bool ok() const { return !error; }
};

// One firmware update of node `node` (1..127). The image is the program followed by its CRC-32
// (IEEE 802.3, as zlib) little-endian: that trailer is the identification 1F56h:01 must show
// after the download. A failure after the loader took over leaves the node in its loader (no
// start is sent); the update can simply be run again, the loader accepts a new image.
// A node that boots before answering the stop or start write (real loaders may reset at once)
// is accepted: the boot-up counts as the answer.
class FirmwareDownload {
 public:
  using Clock = SdoTransfer::Clock;
  using TimePoint = SdoTransfer::TimePoint;

  // Throws std::invalid_argument for a node outside 1..127 or a block size above 127. An image of
  // 4 bytes or less fails at start() (step download, 0x08000020), not here: it comes from a file.
  FirmwareDownload(NodeId node, std::vector<std::uint8_t> image, FirmwareDownloadOptions options,
                   FirmwareStartMode mode = FirmwareStartMode::unknown);

  NodeId node() const { return node_; }
  // The CRC-32 the image's trailer names (0 for an image of 4 bytes or less).
  std::uint32_t expected_identification() const { return expected_; }

  void start(TimePoint now, std::vector<can::Frame>& out);
  // Any frame read on the bus: the node's SDO responses and boot-ups act, the rest is ignored.
  void on_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  // Call once now >= deadline(): ends the current wait (SDO answer or boot-up) as a failure.
  void on_timeout(TimePoint now, std::vector<can::Frame>& out);
  // Gives up for `reason` (e.g. 0x08000021 when the operator cancels), aborting an open SDO
  // transfer toward the node. Nothing happens once finished.
  void abort(std::error_code reason, std::vector<can::Frame>& out);

  TimePoint deadline() const;
  bool finished() const { return result_.has_value(); }
  // Valid once finished().
  const FirmwareResult& result() const { return *result_; }
  // The current step and the image bytes acknowledged so far; a caller that reports progress
  // compares it with what it reported last (the step changes at most seven times).
  FirmwareProgress progress() const;

 private:
  void enter(FirmwareStep step, TimePoint now, std::vector<can::Frame>& out);
  void after_transfer(TimePoint now, std::vector<can::Frame>& out);
  void fail(std::error_code error, std::string detail);

  NodeId node_ = 0;
  std::vector<std::uint8_t> image_;
  FirmwareDownloadOptions options_{};
  FirmwareStartMode mode_ = FirmwareStartMode::unknown;
  std::uint32_t expected_ = 0;
  FirmwareStep step_ = FirmwareStep::probe;
  std::optional<SdoTransfer> transfer_;  // the current step's SDO transfer, when it has one
  TimePoint boot_deadline_ = TimePoint::max();
  std::size_t bytes_done_ = 0;  // after the download step
  std::optional<FirmwareResult> result_;
};

}  // namespace canbridge::canopen
