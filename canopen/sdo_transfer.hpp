// A full CiA 301 SDO client transfer (expedited, segmented, block with CRC, both directions) as a
// pure state machine: frames and an injected clock in, frames and one result out.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_client.hpp"
#include "canopen/sdo_codec.hpp"

namespace canbridge::canopen {

struct SdoTransferOptions {
  // Longest wait for any one answer of the server (CiA 301's SDO timeout). A loader erasing
  // flash may need seconds before it answers a block's end: the caller says so here.
  std::chrono::milliseconds timeout{1000};
  // 0: expedited or segmented only. 1..127: block transfer, accepting at most this many segments
  // per sub-block (upload; a download's sub-blocks are as long as the server asks: CiA 301 gives
  // the client no say there); a server that answers a block initiate with an abort (0x05040001
  // from one without block transfer) is not retried with segmented transfer (the caller decides).
  std::uint8_t block_size = 0;
  // Block upload: the size below which the server may answer with a plain (expedited or
  // segmented) upload instead (CiA 301 protocol switch threshold, "pst"); 0: no switch.
  std::uint8_t protocol_switch_threshold = 0;
};

// One transfer with one node's default SDO server (0x600+N / 0x580+N). Frames are appended to
// `out`, in order; a block download appends a whole sub-block at once. The transfer ends once,
// with result(): success (the uploaded bytes for an upload), an abort the server sent, or one it
// sent the server (timeout 0x05040000, CRC 0x05040004, bad sequence 0x05040003, unexpected
// command 0x05040001, sizes 0x06070010 / 0x06070012 / 0x06070013, or `abort()`'s reason).
class SdoTransfer {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // Throw std::invalid_argument for a node outside 1..127 or a block size above 127.
  static SdoTransfer upload(NodeId node, sdo::Multiplexer mux, SdoTransferOptions options);
  // Any size, including 0 bytes (sent as a segmented download of size 0) and more than 4 GiB is
  // refused (std::invalid_argument).
  static SdoTransfer download(NodeId node, sdo::Multiplexer mux, std::vector<std::uint8_t> data,
                              SdoTransferOptions options);

  NodeId node() const { return node_; }
  sdo::Multiplexer mux() const { return mux_; }
  bool is_upload() const { return upload_; }

  void start(TimePoint now, std::vector<can::Frame>& out);
  // Any frame read on the bus; only the node's SDO responses (0x580+N, 8 bytes) act.
  void on_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  // Ends the transfer with SdoAbort::timeout (telling the server) once now >= deadline().
  void on_timeout(TimePoint now, std::vector<can::Frame>& out);
  // Gives up for `reason` (an SdoAbort, e.g. 0x08000021 when the operator cancels), telling the
  // server when a transfer is open. Nothing happens once finished.
  void abort(std::error_code reason, std::vector<can::Frame>& out);

  TimePoint deadline() const { return finished() ? TimePoint::max() : deadline_; }
  bool finished() const { return finished_; }
  // Valid once finished().
  const SdoResult& result() const { return result_; }
  // Progress: bytes acknowledged by the server (download) or received (upload), and the total
  // (download: the data's size; upload: the size the server indicated, 0 when it gave none).
  std::size_t bytes_done() const { return done_; }
  std::size_t bytes_total() const { return total_; }

 private:
  SdoTransfer() = default;

  NodeId node_ = 0;
  sdo::Multiplexer mux_{};
  bool upload_ = true;
  SdoTransferOptions options_{};
  std::vector<std::uint8_t> data_;  // download: what to send; upload: what arrived
  bool finished_ = false;
  SdoResult result_{};
  TimePoint deadline_ = TimePoint::max();
  std::size_t done_ = 0;
  std::size_t total_ = 0;

  enum class Phase : std::uint8_t {
    idle,       // not started
    initiate,   // initiate request sent, awaiting its response
    segment,    // segmented: a segment (download) or segment request (upload) awaits its answer
    sub_block,  // block download: sub-block sent, awaiting its ack; upload: receiving segments
    block_end,  // block download: end sent, awaiting the confirmation; upload: awaiting the end
    done,
  };
  // What the server's answer in `phase_` is handled by.
  void on_initiate(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void on_upload_initiate(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void on_segment(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void on_download_segment(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void on_upload_segment(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void send_download_segment(TimePoint now, std::vector<can::Frame>& out);
  void send_upload_segment_request(TimePoint now, std::vector<can::Frame>& out);
  void on_block_download_answer(const can::Frame& frame, TimePoint now,
                                std::vector<can::Frame>& out);
  void on_block_upload_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void on_block_upload_end(const can::Frame& frame, std::vector<can::Frame>& out);
  void send_sub_block(TimePoint now, std::vector<can::Frame>& out);
  // An abort from the server for this transfer ends it (true); any other frame: false.
  bool take_server_abort(const can::Frame& frame);
  // An 8-byte request frame on 0x600+N with `command` in byte 0 and the rest zero.
  can::Frame request(std::uint8_t command) const;
  void await_answer(TimePoint now, can::Frame frame, std::vector<can::Frame>& out);
  void finish(std::error_code error);
  // Ends the transfer for `abort` and tells the server.
  void fail(SdoAbort abort, std::vector<can::Frame>& out);

  Phase phase_ = Phase::idle;
  bool block_ = false;            // the block protocol runs (a protocol switch falls back to plain)
  bool toggle_ = false;           // segmented: the toggle bit of the segment in flight
  std::size_t in_flight_ = 0;     // segmented download: data bytes of the segment awaiting its ack
  bool size_indicated_ = false;   // upload: the server gave the size (total_)
  bool server_crc_ = false;       // block: the server checks (download) or sends (upload) CRC
  std::uint8_t block_size_ = 0;   // block: segments in the current sub-block
  std::uint8_t seqno_ = 0;        // block download: segments sent; upload: last in-order seqno
  bool last_segment_ = false;     // block: the segment with the last byte was sent / received
  std::size_t acknowledged_ = 0;  // block download: bytes the server confirmed
};

}  // namespace canbridge::canopen
