#include "canopen/firmware_download.hpp"

#include <cstdio>
#include <stdexcept>
#include <utility>

#include "canopen/little_endian.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::canopen {

namespace {

namespace fo = firmware_objects;

constexpr std::size_t kCrcSize = 4;

std::string hex32(std::uint32_t value) {
  char text[16];
  std::snprintf(text, sizeof text, "0x%08X", static_cast<unsigned>(value));
  return text;
}

std::string cob_text(std::uint16_t base, NodeId node) {
  char text[24];
  std::snprintf(text, sizeof text, "0x%03X", static_cast<unsigned>(base + node));
  return text;
}

bool is_boot_up(const can::Frame& frame, std::uint32_t cob_id) {
  return frame.is_standard_data() && frame.id == cob_id && frame.len == 1 && frame.data[0] == 0;
}

// What each SDO step does, for the failure's detail.
const char* sdo_action(FirmwareStep step) {
  switch (step) {
    case FirmwareStep::probe:
      return "reading 1F57h:01 (flash status)";
    case FirmwareStep::stop:
      return "writing 1F51h:01 = 0 (stop program)";
    case FirmwareStep::download:
      return "downloading the image to 1F50h:01";
    case FirmwareStep::verify:
      return "reading 1F56h:01 (program identification)";
    case FirmwareStep::start:
      return "writing 1F51h:01 = 1 (start program)";
    default:
      return "";
  }
}

}  // namespace

const char* to_string(FirmwareStep step) {
  switch (step) {
    case FirmwareStep::probe:
      return "probe";
    case FirmwareStep::stop:
      return "stop";
    case FirmwareStep::wait_loader:
      return "wait_loader";
    case FirmwareStep::download:
      return "download";
    case FirmwareStep::verify:
      return "verify";
    case FirmwareStep::start:
      return "start";
    case FirmwareStep::wait_application:
      return "wait_application";
    case FirmwareStep::done:
      return "done";
  }
  return "?";
}

FirmwareDownload::FirmwareDownload(NodeId node, std::vector<std::uint8_t> image,
                                   FirmwareDownloadOptions options, FirmwareStartMode mode)
    : node_(node), image_(std::move(image)), options_(options), mode_(mode) {
  if (node_ == 0 || node_ > kMaxNodeId) {
    throw std::invalid_argument("firmware download: node id outside 1..127");
  }
  if (options_.block_size > 127) {
    throw std::invalid_argument("firmware download: block size above 127");
  }
  if (image_.size() > kCrcSize) {
    expected_ = load_le32(std::span<const std::uint8_t>(image_).last(kCrcSize));
  }
}

void FirmwareDownload::start(TimePoint now, std::vector<can::Frame>& out) {
  if (image_.size() <= kCrcSize) {
    step_ = FirmwareStep::download;
    fail(SdoAbort::cannot_transfer, "an image of " + std::to_string(image_.size()) +
                                        " bytes holds no program before its 4-byte CRC-32");
    return;
  }
  switch (mode_) {
    case FirmwareStartMode::unknown:
      enter(FirmwareStep::probe, now, out);
      break;
    case FirmwareStartMode::application:
      enter(FirmwareStep::stop, now, out);
      break;
    case FirmwareStartMode::loader:
      enter(FirmwareStep::download, now, out);
      break;
  }
}

void FirmwareDownload::enter(FirmwareStep step, TimePoint now, std::vector<can::Frame>& out) {
  step_ = step;
  transfer_.reset();
  boot_deadline_ = TimePoint::max();
  SdoTransferOptions sdo;
  sdo.timeout = options_.answer_timeout;
  switch (step) {
    case FirmwareStep::probe:
      transfer_ = SdoTransfer::upload(node_, {fo::flash_status, 1}, sdo);
      break;
    case FirmwareStep::stop:
      transfer_ = SdoTransfer::download(node_, {fo::program_control, 1}, {0}, sdo);
      break;
    case FirmwareStep::download:
      sdo.block_size = options_.block_size;
      transfer_ = SdoTransfer::download(node_, {fo::program_data, 1}, image_, sdo);
      break;
    case FirmwareStep::verify:
      transfer_ = SdoTransfer::upload(node_, {fo::program_identification, 1}, sdo);
      break;
    case FirmwareStep::start:
      transfer_ = SdoTransfer::download(node_, {fo::program_control, 1}, {1}, sdo);
      break;
    case FirmwareStep::wait_loader:
    case FirmwareStep::wait_application:
      boot_deadline_ = now + options_.boot_timeout;
      return;
    case FirmwareStep::done:
      result_ = FirmwareResult{{}, FirmwareStep::done, {}};
      return;
  }
  transfer_->start(now, out);
  if (transfer_->finished()) after_transfer(now, out);
}

void FirmwareDownload::on_frame(const can::Frame& frame, TimePoint now,
                                std::vector<can::Frame>& out) {
  if (finished()) return;
  // A node may reset as soon as it takes the stop or start command, before (or instead of)
  // answering it: its boot-up is then the answer. A late answer cannot follow a reset.
  if (is_boot_up(frame, fo::loader_boot_up + node_)) {
    if (step_ == FirmwareStep::stop || step_ == FirmwareStep::wait_loader) {
      enter(FirmwareStep::download, now, out);
    }
    return;
  }
  if (is_boot_up(frame, cob::heartbeat + node_)) {
    if (step_ == FirmwareStep::start || step_ == FirmwareStep::wait_application) {
      enter(FirmwareStep::done, now, out);
    }
    return;
  }
  if (!transfer_ || transfer_->finished()) return;
  transfer_->on_frame(frame, now, out);
  if (transfer_->finished()) after_transfer(now, out);
}

void FirmwareDownload::on_timeout(TimePoint now, std::vector<can::Frame>& out) {
  if (finished()) return;
  if (transfer_ && !transfer_->finished()) {
    transfer_->on_timeout(now, out);
    if (transfer_->finished()) after_transfer(now, out);
    return;
  }
  if (now < boot_deadline_) return;
  const bool loader = step_ == FirmwareStep::wait_loader;
  fail(SdoAbort::cannot_transfer,
       std::string("no ") + (loader ? "loader" : "application") + " boot-up on " +
           cob_text(loader ? fo::loader_boot_up : cob::heartbeat, node_) + " within " +
           std::to_string(options_.boot_timeout.count()) + " ms");
}

void FirmwareDownload::abort(std::error_code reason, std::vector<can::Frame>& out) {
  if (finished()) return;
  if (transfer_ && !transfer_->finished()) transfer_->abort(reason, out);
  fail(reason, "given up by the caller");
}

FirmwareDownload::TimePoint FirmwareDownload::deadline() const {
  if (finished()) return TimePoint::max();
  if (transfer_ && !transfer_->finished()) return transfer_->deadline();
  return boot_deadline_;
}

FirmwareProgress FirmwareDownload::progress() const {
  FirmwareProgress p;
  p.step = step_;
  p.bytes_total = image_.size();
  p.bytes_done =
      step_ == FirmwareStep::download && transfer_ ? transfer_->bytes_done() : bytes_done_;
  return p;
}

void FirmwareDownload::after_transfer(TimePoint now, std::vector<can::Frame>& out) {
  const SdoResult& r = transfer_->result();
  if (step_ == FirmwareStep::download) bytes_done_ = transfer_->bytes_done();
  if (step_ == FirmwareStep::probe) {
    // Only the loader serves the flash status; the application does not have the object.
    if (r.ok()) {
      enter(FirmwareStep::download, now, out);
    } else if (r.error == SdoAbort::no_object || r.error == SdoAbort::no_sub_index) {
      enter(FirmwareStep::stop, now, out);
    } else {
      fail(r.error, std::string(sdo_action(step_)) + ": " + r.error.message());
    }
    return;
  }
  if (!r.ok()) {
    fail(r.error, std::string(sdo_action(step_)) + ": " + r.error.message());
    return;
  }
  switch (step_) {
    case FirmwareStep::stop:
      enter(FirmwareStep::wait_loader, now, out);
      break;
    case FirmwareStep::download:
      enter(FirmwareStep::verify, now, out);
      break;
    case FirmwareStep::verify: {
      const std::uint32_t shown = load_le32(r.data);
      if (r.data.size() != 4 || shown != expected_) {
        // The loader publishes the CRC of what it accepted (0 for a refused image): anything
        // else means the program in flash is not this image, so it must not be started.
        fail(SdoAbort::cannot_transfer, "1F56h:01 is " + hex32(shown) + ", the image's CRC-32 is " +
                                            hex32(expected_) + ": the node did not accept it");
        return;
      }
      enter(FirmwareStep::start, now, out);
      break;
    }
    case FirmwareStep::start:
      enter(FirmwareStep::wait_application, now, out);
      break;
    default:
      break;
  }
}

void FirmwareDownload::fail(std::error_code error, std::string detail) {
  // Progress keeps what the node confirmed, also after a cancel in the middle of the image.
  if (step_ == FirmwareStep::download && transfer_) bytes_done_ = transfer_->bytes_done();
  transfer_.reset();
  boot_deadline_ = TimePoint::max();
  result_ = FirmwareResult{error, step_, std::move(detail)};
}

}  // namespace canbridge::canopen
