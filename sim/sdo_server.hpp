// A simulated node's CiA 301 SDO server: expedited, segmented and block transfers between one SDO
// channel and an ObjectDictionary, as a pure state machine (frames and an injected clock in,
// response frames out).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_abort.hpp"
#include "canopen/sdo_codec.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

// Which transfer protocols the server accepts; each level includes the ones before. Requests for
// a protocol above the level are refused with 0x05040001, as by a device that lacks it.
enum class SdoLevel : std::uint8_t { expedited, segmented, block };

struct SdoServerOptions {
  canopen::NodeId node_id = 1;  // requests on 0x600+id, responses on 0x580+id
  SdoLevel level = SdoLevel::block;
  std::chrono::milliseconds timeout{1000};  // idle time inside a segmented/block transfer
  std::uint8_t max_block_size = 127;        // blksize the server grants/proposes (1..127)
};

// One SDO server channel. It serves one transfer at a time (CiA 301); expedited transfers finish
// within one request, the others keep state between frames until done, aborted or timed out.
//
// Decisions beyond the letter of CiA 301:
// - Frames that are not 8-byte standard data frames are ignored (they are not SDO).
// - A request that does not fit the open transfer, including a new initiate request, aborts the
//   open transfer with 0x05040001 (naming its multiplexer) and is itself dropped: the server is
//   idle afterwards and the client retries, as with CANopenNode's server. While a block
//   download sub-block is being received every frame is a segment (byte 0 = c | seqno), except
//   exactly 0x80, the client's abort.
// - A client abort ends the transfer silently; one received while idle is ignored (counted only).
// - Download checks that need no data (object, sub-index, write access, indicated size) run at
//   initiate, so a doomed transfer fails before its data is sent; the write guard runs with the
//   one od.write() when the data is complete.
// - An expedited download without size indication writes as many of its 4 bytes as a
//   fixed-size entry holds, all 4 to a string or domain.
// - Values of 1..4 bytes upload expedited; empty values and longer ones need segmented (or
//   block) transfer.
// - In a block download, out-of-order segments are ignored until the sub-block ends (seqno ==
//   blksize or the c bit); the acknowledgement names the last in-order seqno and the client
//   repeats from there. A lost final segment of a sub-block therefore ends in the timeout.
class SdoServer {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;

  struct Counters {
    std::uint64_t transfers_ok = 0;
    std::uint64_t aborts_sent = 0;  // includes the timeouts' aborts
    std::uint64_t aborts_received = 0;
    std::uint64_t timeouts = 0;
  };

  // std::invalid_argument for a node id outside 1..127, a block size outside 1..127, a
  // non-positive timeout or an unknown level.
  SdoServer(ObjectDictionary& od, const SdoServerOptions& options);

  // A frame received on 0x600+node (the caller filters the COB-ID). Appends the responses, all
  // 8-byte frames on 0x580+node, to `out`.
  void on_request(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  // Once now >= next_deadline(), aborts the open transfer with 0x05040000 (sending the abort).
  void on_tick(TimePoint now, std::vector<can::Frame>& out);
  // TimePoint::max() when idle.
  TimePoint next_deadline() const;

  // Drops any transfer silently (NMT reset, state change).
  void reset();
  // Node-id change (std::invalid_argument outside 1..127); implies reset().
  void set_node_id(canopen::NodeId id);

  bool busy() const { return state_ != State::idle; }
  const Counters& counters() const { return counters_; }
  const SdoServerOptions& options() const { return options_; }

 private:
  enum class State : std::uint8_t {
    idle,
    segmented_download,        // awaiting download segment requests
    segmented_upload,          // awaiting upload segment requests
    block_download_sub_block,  // receiving the segments of a sub-block
    block_download_end,        // last segment acknowledged; awaiting end block download
    block_upload_start,        // initiate answered; awaiting start upload
    block_upload_ack,          // sub-block sent; awaiting the client's acknowledgement
    block_upload_end,          // end block upload sent; awaiting the client's end response
  };

  // Idle: initiate requests.
  void dispatch_initiate(const can::Frame& frame, std::vector<can::Frame>& out);
  void initiate_upload(canopen::sdo::Multiplexer mux, std::vector<can::Frame>& out);
  void initiate_download(const can::Frame& frame, std::vector<can::Frame>& out);
  void initiate_block_upload(const can::Frame& frame, std::vector<can::Frame>& out);
  void initiate_block_download(const can::Frame& frame, std::vector<can::Frame>& out);
  // Inside a transfer: one function per expected request.
  void download_segment(const can::Frame& frame, std::vector<can::Frame>& out);
  void upload_segment(const can::Frame& frame, std::vector<can::Frame>& out);
  void block_download_segment(const can::Frame& frame, std::vector<can::Frame>& out);
  void end_block_download(const can::Frame& frame, std::vector<can::Frame>& out);
  void start_block_upload(const can::Frame& frame, std::vector<can::Frame>& out);
  void block_upload_ack(const can::Frame& frame, std::vector<can::Frame>& out);
  void end_block_upload(const can::Frame& frame, std::vector<can::Frame>& out);

  // What a download of `size` bytes (nullopt: not indicated) to `mux` may carry, decided before
  // any data arrives.
  struct DownloadLimit {
    std::error_code error;     // why the download cannot succeed at all
    std::size_t capacity = 0;  // the most data bytes it may carry
    canopen::SdoAbort overflow = canopen::SdoAbort::length_mismatch;  // abort for more than that
  };
  DownloadLimit check_download(canopen::sdo::Multiplexer mux,
                               std::optional<std::uint32_t> size) const;
  // Writes the completed download; false (after aborting) when the dictionary refuses.
  bool commit_download(std::vector<can::Frame>& out);
  void send_sub_block(std::vector<can::Frame>& out);

  // An 8-byte response frame on 0x580+node with `command` in byte 0, the rest zero.
  can::Frame response(std::uint8_t command) const;
  void begin(State state, canopen::sdo::Multiplexer mux);
  void finish();
  void abort(canopen::sdo::Multiplexer mux, std::error_code error, std::vector<can::Frame>& out);
  // Aborts the open transfer.
  void abort(std::error_code error, std::vector<can::Frame>& out) { abort(mux_, error, out); }

  ObjectDictionary& od_;
  SdoServerOptions options_;
  Counters counters_;

  State state_ = State::idle;
  canopen::sdo::Multiplexer mux_;
  TimePoint deadline_ = TimePoint::max();
  // Upload: a snapshot of the value, so a device write during the transfer cannot tear it.
  // Download: the bytes received so far (block: including the last segment's padding).
  std::vector<std::uint8_t> data_;
  std::size_t offset_ = 0;  // upload: bytes sent (segmented) or acknowledged (block)
  bool toggle_ = false;     // segmented: toggle bit the next segment must carry
  std::optional<std::uint32_t> indicated_size_;
  std::size_t capacity_ = 0;  // download: the most data bytes the transfer may carry
  canopen::SdoAbort overflow_ = canopen::SdoAbort::length_mismatch;  // for data beyond capacity_
  bool client_crc_ = false;
  std::uint8_t block_size_ = 0;  // segments in the current sub-block
  std::uint8_t seqno_ = 0;       // block download: last in-order seqno; upload: segments sent
  bool last_segment_ = false;    // block: the segment carrying the last byte was received/sent
};

}  // namespace canbridge::sim
