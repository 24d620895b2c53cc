// Follows the transfers of one SDO channel so that the values of objects that hold COB-IDs or node
// ids (value_kind) are rewritten whichever SDO protocol carries them: expedited, segmented or
// block, downloads and uploads. A pure state machine: frames in, frames rewritten in place.
#pragma once

#include <array>
#include <cstdint>
#include <optional>

#include "can/frame.hpp"
#include "canopen/sdo_value_translator.hpp"

namespace canbridge::canopen::sdo {

// One instance per SDO channel (the bridge keeps one per module-bus node) sees every request the
// master sends to the node and every response the node sends back, in the order the bridge
// forwards them.
//
// Where values are found. Every listed value is 4 bytes (1 for node_id), so a transfer that
// carries it whole has exactly one data segment:
// - expedited download request / expedited upload response: the frame names its object itself;
//   rewritten as by rewrite_request / rewrite_response, in every phase whose frames are commands
//   (not inside a block sub-block).
// - segmented: the first download segment request (after the server's initiate download
//   response) or the first upload segment response (after a non-expedited initiate upload
//   response), when it is also the last (c = 1) and carries exactly the value's size (7 - n).
// - block: the segment with seqno 1 of the first sub-block (again after a sub-block whose
//   acknowledgement was 0), when it is also the last (c = 1). The end frame (client's end block
//   download request, server's end block upload response) carries the CRC of the data; when CRC
//   is in use (cc in the initiate request and sc in the initiate response, CiA 301) and the value
//   was rewritten, the CRC is corrected by the difference crc(rewritten) ^ crc(original) over the
//   7 - n data bytes: a correct CRC stays correct for the new data, a wrong one stays equally
//   wrong, so the receiver still detects a corrupted transfer.
// - block upload answered by the SDO upload protocol (protocol switch threshold): the expedited
//   or segmented initiate upload response is followed as above.
// A transfer whose initiate indicates a size other than the value's, whose response names another
// object, or whose value spans more than one segment is followed but never rewritten: the node
// (or master) refuses or accepts it as it would without the bridge.
//
// Decision: the phases of EVERY transfer are followed, listed object or not. Block segments carry
// c | seqno in byte 0, which for seqno 0x21..0x7F looks exactly like a command: download segment
// 0x23 00 18 01 .. is also an expedited download of 1800h sub 1, upload segment 0x43 00 12 01 ..
// an expedited upload response of 1200h sub 1. A tracker idle outside listed transfers would
// rewrite such segments of unlisted (e.g. 32 KiB domain) transfers. Following phases costs a few
// bytes of state and O(1) per frame, with no allocation; the frames of unlisted transfers are
// never modified. (Segmented transfers could not be confused this way: their segments' command
// specifiers differ from every initiate's, but they are followed the same way.)
// Inside a block sub-block the sender's frames are all segments except exactly 0x80 (an abort:
// seqno 0 is invalid); the sub-block ends with the receiver's acknowledgement, which says whether
// the last segment arrived (end phase next) or which segments the next sub-block repeats.
//
// The tracker mirrors how the server reads the client's frames and the client the server's:
// - Abort (either way) ends the transfer. A client initiate (not inside a download sub-block)
//   starts tracking that transfer, whatever was open.
// - A frame that does not fit the phase ends the transfer (idle) and is then read as in idle:
//   only the self-describing expedited frames are rewritten, everything else passes unchanged.
// - Frames that are not 8-byte standard data frames are not SDO: unchanged, state kept.
// - Started (or reset()) in the middle of a block transfer, the tracker cannot know that frames
//   are segments until the next initiate; the bridge calls reset() when the channel starts over.
// A write the server confirmed: an expedited download of `mux` (its initiate download response
// names the same object). The bridge learns from it what the node now holds, e.g. the heartbeat
// producer time (1017h) its node table watches the node with.
struct ConfirmedWrite {
  Multiplexer mux;
  std::uint32_t value = 0;  // the bytes the node received, little-endian; unsent bytes are 0
  std::uint8_t size = 0;    // 1..4; 4 when the client did not indicate the size
  friend bool operator==(const ConfirmedWrite&, const ConfirmedWrite&) = default;
};

class ValueTransferTracker {
 public:
  // A client -> server frame (surface master -> node), rewritten in place with `to_local`.
  ValueRewrite on_request(can::Frame& request, const IdMapping& to_local);
  // A server -> client frame (node -> surface master), rewritten in place with `to_surface`.
  // The end frame of a block upload whose CRC was corrected reports `rewritten` as well (as does
  // the end block download request), so a rewritten block transfer reports it on two frames.
  ValueRewrite on_response(can::Frame& response, const IdMapping& to_surface);
  // Forgets any open transfer, e.g. the node rebooted or the link dropped.
  void reset();
  // Set by the on_response() whose frame confirmed an expedited download of the client's last
  // request; cleared by the next on_request() or on_response(). A request from a master on the
  // module bus is fed with on_request() too (its copy, with an empty IdMapping) so that its
  // writes are seen and its transfer's frames are followed.
  const std::optional<ConfirmedWrite>& confirmed_write() const { return confirmed_; }

  // No transfer open: the next client frame is read as an initiate.
  bool idle() const { return phase_ == Phase::idle; }

 private:
  enum class Phase : std::uint8_t {
    idle,
    download_initiated,        // segmented initiate download request sent
    segmented_download,        // server agreed: client download segments
    upload_initiated,          // initiate upload request sent
    segmented_upload,          // non-expedited initiate upload response: server upload segments
    block_download_initiated,  // initiate block download request sent
    block_download_sub_block,  // every client frame is a segment until the server's ack
    block_download_end,        // last segment acknowledged: awaiting end block download request
    block_upload_initiated,    // initiate block upload request sent
    block_upload_start,        // server agreed: awaiting start block upload
    block_upload_sub_block,    // every server frame is a segment until the client's ack
    block_upload_end,          // last segment acknowledged: awaiting end block upload response
  };

  // Starts following a transfer of `mux`, whose value is of `kind` (none: never rewritten).
  void begin(Phase phase, Multiplexer mux, ValueKind kind);
  // The server's initiate response names `mux`: if not the requested object, nothing is rewritten.
  void confirm(Multiplexer mux);
  ValueRewrite initiate_download(can::Frame& request, const IdMapping& to_local);
  // The frame read against the open transfer's phase; nullopt when it ends or does not fit
  // the transfer (the caller then forgets it).
  std::optional<ValueRewrite> followed_request(can::Frame& request, const IdMapping& to_local);
  std::optional<ValueRewrite> download_segment(can::Frame& request, const IdMapping& to_local);
  std::optional<ValueRewrite> block_upload_request(const can::Frame& request);
  std::optional<ValueRewrite> block_download_request(can::Frame& request);
  std::optional<ValueRewrite> followed_response(can::Frame& response, const IdMapping& to_surface);
  ValueRewrite initiate_upload_response(can::Frame& response, const IdMapping& to_surface);
  std::optional<ValueRewrite> initiate_download_response(const can::Frame& response);
  std::optional<ValueRewrite> upload_segment(can::Frame& response, const IdMapping& to_surface);
  std::optional<ValueRewrite> block_download_response(const can::Frame& response);
  std::optional<ValueRewrite> block_upload_response(can::Frame& response);
  // A frame whose data bytes 1..7 hold the start of the value (segment), when `whole`.
  ValueRewrite first_segment(can::Frame& segment, bool whole, const IdMapping& map);
  ValueRewrite block_segment(can::Frame& segment, const IdMapping& map);
  // The receiver's acknowledgement of a sub-block: `end` when it covers the last segment.
  void block_ack(std::uint8_t ackseq, Phase end);
  ValueRewrite correct_crc(can::Frame& end);

  Phase phase_ = Phase::idle;
  Multiplexer mux_;
  ValueKind kind_ = ValueKind::none;  // none: the transfer's value is never rewritten
  bool client_crc_ = false;           // cc of the initiate block request
  bool server_crc_ = false;           // sc of the initiate block response
  bool at_start_ = false;             // the next data segment starts the transfer's data
  bool last_sent_ = false;            // segmented download: the segment with c = 1 went out
  std::uint8_t last_seqno_ = 0;       // block: seqno of this sub-block's segment with c = 1, or 0
  // Block: data bytes 1..7 of the segment whose value was rewritten, before and after, for the
  // CRC correction; valid when `rewritten_` is true.
  bool rewritten_ = false;
  std::array<std::uint8_t, 7> original_{};
  std::array<std::uint8_t, 7> replaced_{};
  // The expedited download request awaiting the server's response (idle phase), and a write
  // the last response confirmed.
  std::optional<ConfirmedWrite> requested_;
  std::optional<ConfirmedWrite> confirmed_;
};

}  // namespace canbridge::canopen::sdo
