// The gateway's sender side of RPDOP (docs/pdop.md section 4), one per pdop module bus: packets
// from the surface are cut into fragments toward a node's RPDO1..4 and paced by the node's
// acknowledgements (0x680 + node), with the document's timeouts, acknowledgement requests,
// aborts and resynchronisation; each packet ends in exactly one outcome for whoever asked.
// Pure: frames and the (steady) time in, frames to send and outcomes out; no sockets, no timers,
// no logging. The gateway arms one timer at next_deadline() and calls tick() when it fires.
//
// Per (node, rpdo) one packet is in transfer at a time; further packets wait in a bounded queue
// (queue_per_rpdo, and max_held_bytes over the whole bus) and are refused with `refused_busy`
// beyond it. Transfers to different nodes, and to different RPDOs of one node, run concurrently.
//
// Choices where docs/pdop.md leaves the sender free (each keeps to the document):
// - `window` bounds only the first burst of a packet; then each acknowledgement's
//   received + credit is the limit (credit 0: wait). Fragments below an earlier limit are
//   already sent, so only a request's answer, which moves the sender back to its `received`,
//   can make it send less than before. Acknowledgements whose `received` is below one already
//   taken for the packet, or above what was ever sent, are stale and ignored.
// - The acknowledgement timer runs from the last fragment sent or acknowledgement taken, so a
//   node that answered with credit 0 is asked again after ack_timeout.
// - After any abort (receiver abort, timeout, cancel) the segmenter sends its abort frame at
//   once and waits for the node's 0x85 before the next packet on that RPDO (re-sending the
//   abort every ack_timeout, `retries` times; then it goes on, sending an abort frame again
//   before the next packet). Every acknowledgement before the 0x85 belongs to the old packet,
//   so none can be taken for the next one. A 0x85 at any other time is ignored.
// - An acknowledgement request to a node holds new packets to that node (any RPDO) for
//   ack_timeout: an answer about a packet the node finished earlier cannot be taken for a
//   packet started after the request (section 4.3 "answered for the packet before it").
// The request/answer rules assume a round trip (fragment out, acknowledgement back) shorter
// than ack_timeout; a slower answer may be taken for a later one.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/pdop.hpp"

namespace canbridge::bridge {

using canopen::NodeId;

// docs/pdop.md section 5, the sender's side (per module).
struct PdopSegmenterOptions {
  std::size_t max_packet_bytes = 4096;         // 1..524,280
  std::uint8_t window = 4;                     // 1..255: fragments sent before the first ack
  std::chrono::milliseconds ack_timeout{100};  // 1 ms..10 s
  unsigned retries = 3;                        // 0..10 unanswered requests before giving up
  // Packets waiting behind the one in transfer, per (node, rpdo): 0..1024 (0: one at a time,
  // a second submit is refused).
  std::size_t queue_per_rpdo = 8;
  // Bytes of all packets held (in transfer and waiting) on the bus: max_packet_bytes..1 GiB.
  std::size_t max_held_bytes = std::size_t{1} << 20;
};

// Every problem of `options`, each "field: message" (empty when valid), for startup validation.
std::vector<std::string> validate(const PdopSegmenterOptions& options);

enum class PdopResult : std::uint8_t {
  complete,         // the node acknowledged status 1 with received = all fragments
  receiver_abort,   // the node aborted (`status`: 0x80..0x84, or another 0x80+ code)
  timeout,          // `retries` acknowledgement requests unanswered; the segmenter aborted
  cancelled,        // cancel() / cancel_node(); aborted on the bus if it had started
  refused_busy,     // queue of its (node, rpdo) full, or max_held_bytes reached
  refused_size,     // empty or longer than max_packet_bytes
  refused_address,  // node outside 1..31 or rpdo outside 1..4
};
const char* to_string(PdopResult result);

struct PdopOutcome {
  std::uint64_t request_id = 0;
  NodeId node = 0;
  unsigned rpdo = 0;
  PdopResult result = PdopResult::complete;
  // The node's status: complete for `complete`, its abort code for `receiver_abort`,
  // in_progress otherwise.
  canopen::pdop::AckStatus status = canopen::pdop::AckStatus::in_progress;
  std::uint32_t fragments = 0;                     // of the packet (0 when refused)
  std::uint32_t fragments_sent = 0;                // fragment frames sent, retransmissions included
  std::uint32_t retransmissions = 0;               // fragments sent again after a request's answer
  std::uint32_t ack_requests = 0;                  // remote frames sent for this packet
  std::chrono::steady_clock::duration elapsed{0};  // from submit() to the outcome
  friend bool operator==(const PdopOutcome&, const PdopOutcome&) = default;
};
// e.g. "request 7 node 3 RPDO1: receiver_abort 0x80 (5 fragments, 6 sent, 1 again, 1 request,
// 12 ms)": one line for the gateway's log.
std::string to_string(const PdopOutcome& outcome);

class PdopSegmenter {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  using Duration = Clock::duration;

  // Appended to, never cleared here.
  struct Output {
    std::vector<can::Frame> frames;  // to write to the module bus, in order
    std::vector<PdopOutcome> outcomes;
  };

  struct Counters {
    std::uint64_t submitted = 0;  // submit() calls, refused ones included
    std::uint64_t complete = 0;
    std::uint64_t receiver_aborts = 0;
    std::uint64_t timeouts = 0;
    std::uint64_t cancelled = 0;
    std::uint64_t refused = 0;
    std::uint64_t fragments_sent = 0;
    std::uint64_t retransmissions = 0;
    std::uint64_t ack_requests = 0;    // remote frames sent
    std::uint64_t abort_frames = 0;    // sender aborts sent (re-sends included)
    std::uint64_t acks = 0;            // acknowledgements that moved a transfer
    std::uint64_t ignored_acks = 0;    // stale, unexpected or for no transfer
    std::uint64_t resync_gave_up = 0;  // no 0x85 after retries + 1 abort frames
  };

  // Throws std::invalid_argument naming the first problem validate() finds.
  explicit PdopSegmenter(PdopSegmenterOptions options = {});

  // Queues `packet` for RPDO `rpdo` (1..4) of `node` (1..31), and starts it when its RPDO is
  // free. Refusals are reported at once in out.outcomes, as every other outcome is later.
  void submit(NodeId node, unsigned rpdo, std::vector<std::uint8_t> packet,
              std::uint64_t request_id, TimePoint now, Output& out);

  // Every frame read on the module bus. Only acknowledgements (standard data frames of 5 bytes
  // on 0x681..0x69F naming RPDO 1..4) are looked at; any other frame costs two compares.
  // Returns true when the frame was an acknowledgement (used or ignored).
  bool on_frame(const can::Frame& frame, TimePoint now, Output& out);

  // Timeouts up to `now`: acknowledgement requests, giving up, abort re-sends, held packets.
  void tick(TimePoint now, Output& out);
  // The earliest time tick() has something to do; nullopt when nothing waits on time.
  std::optional<TimePoint> next_deadline() const;

  // Ends the packet `request_id` with `cancelled`: a waiting one leaves its queue, one in
  // transfer is aborted on the bus. False when no packet has that id.
  bool cancel(std::uint64_t request_id, TimePoint now, Output& out);
  // Cancels every packet to `node` (e.g. it rebooted); returns how many.
  std::size_t cancel_node(NodeId node, TimePoint now, Output& out);

  // The request in transfer on (node, rpdo), if any.
  std::optional<std::uint64_t> active_request(NodeId node, unsigned rpdo) const;
  std::size_t queued(NodeId node, unsigned rpdo) const;  // waiting behind the active one
  std::size_t held_bytes() const { return held_bytes_; }
  const PdopSegmenterOptions& options() const { return options_; }
  const Counters& counters() const { return counters_; }

 private:
  static constexpr std::size_t kRpdos = 4;
  static constexpr std::size_t kStreams = canopen::pdop::kMaxNode * kRpdos;

  struct Request {
    std::uint64_t id = 0;
    std::vector<std::uint8_t> bytes;
    TimePoint submitted{};
  };
  enum class Phase : std::uint8_t {
    idle,     // nothing in transfer (packets may wait for the node's request hold)
    sending,  // fragments out, acknowledgements in
    resync,   // abort frame sent, waiting for the node's 0x85
  };
  struct Stream {
    Phase phase = Phase::idle;
    Request request;              // in transfer (sending)
    std::uint32_t fragments = 0;  // of the packet in transfer
    std::uint32_t next = 0;       // next fragment to send
    std::uint32_t limit = 0;      // fragments below this may be sent
    std::uint32_t sent_high = 0;  // fragments ever sent: 0..sent_high-1
    std::uint32_t acked = 0;      // highest `received` taken for this packet
    std::uint32_t fragments_sent = 0;
    std::uint32_t retransmissions = 0;
    std::uint32_t requests = 0;    // for this packet, all of them
    unsigned unanswered = 0;       // requests in a row without an answer
    bool awaiting_answer = false;  // a request is out: the next ack may move `next` back
    bool abort_first = false;      // send an abort frame before the next packet
    unsigned abort_sends = 0;      // resync: abort frames sent for this resync
    TimePoint deadline = TimePoint::max();
    std::deque<Request> waiting;
  };

  Stream& stream(NodeId node, unsigned rpdo) { return streams_[(node - 1u) * kRpdos + rpdo - 1]; }
  const Stream& stream(NodeId node, unsigned rpdo) const {
    return streams_[(node - 1u) * kRpdos + rpdo - 1];
  }
  void on_ack(NodeId node, const canopen::pdop::Ack& ack, TimePoint now, Output& out);
  void on_timeout(NodeId node, unsigned rpdo, TimePoint now, Output& out);
  void try_start(NodeId node, unsigned rpdo, TimePoint now, Output& out);
  void send_window(NodeId node, unsigned rpdo, TimePoint now, Output& out);
  void send_request(NodeId node, unsigned rpdo, TimePoint now, Output& out);
  void send_abort(NodeId node, unsigned rpdo, Output& out);
  void begin_resync(NodeId node, unsigned rpdo, TimePoint now, Output& out);
  void finish(NodeId node, unsigned rpdo, PdopResult result, canopen::pdop::AckStatus status,
              TimePoint now, Output& out);
  void refuse(NodeId node, unsigned rpdo, PdopResult result, std::uint64_t request_id, Output& out);
  void set_deadline(Stream& s, TimePoint deadline);
  TimePoint scan_earliest() const;

  PdopSegmenterOptions options_;
  Duration ack_timeout_;
  std::array<Stream, kStreams> streams_{};
  // Per node (index = node id): no new packet starts before this (request answers in flight),
  // and the time of the last request sent (one request per node and instant).
  std::array<TimePoint, canopen::pdop::kMaxNode + 1> hold_until_{};
  std::array<std::optional<TimePoint>, canopen::pdop::kMaxNode + 1> last_request_{};
  std::size_t held_bytes_ = 0;
  Counters counters_;
  mutable TimePoint earliest_ = TimePoint::max();
  mutable bool earliest_dirty_ = false;
};

}  // namespace canbridge::bridge
