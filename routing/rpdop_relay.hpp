// The surface's receiver side of RPDOP (docs/pdop.md section 4, store and forward; issue 6): a
// master on the surface bus sends PDO Packets to a pdop node behind a gateway as if the node sat
// on the surface bus; the relay takes the fragments with the acknowledgements of section 4,
// hands each complete packet on (the gateway segments it toward the node with the node's own flow
// control) and gives the master the packet's final acknowledgement only when the gateway reports
// the node's outcome. Pure: frames, outcomes and the steady-clock time in, frames and packets out;
// no sockets, timers or logging. The surface arms one timer at next_deadline().
//
// Per (surface node 1..31, RPDO 1..4) one stream, like a node's receiver (section 4.2, 4.5),
// with one more phase: `forwarded`, the last fragment taken and the packet handed on, its
// outcome not known yet. An acknowledgement request in that phase is answered "in progress,
// received = all fragments, credit 0": the sender has nothing left to send and waits (it asks
// again after its ack_timeout; an answered request does not count toward its retries:
// bridge::PdopSegmenter takes it so, docs/pdop.md section 4.3). A master that waits no longer
// than its retries allow would abort (0x85 answered, the outcome then stale).
//
// Choices where section 4 says nothing, because a node never has this phase:
// - A fragment (any t, any c) while forwarded is dropped, counted in dropped_fragments and not
//   answered; the stream stays forwarded. A conforming sender sends none (it has not seen
//   status 1); what arrives is a repeat of the last fragment (double reception) or a sender that
//   did not wait. A toggle abort would tell the master its packet failed while the node may
//   still take it (a retry would deliver it twice), and starting a packet would need a second
//   buffer and leave the final acknowledgement ambiguous. The master's way out is its abort
//   frame: answered 0x85 as always, the stream goes idle and the outcome, when it comes, is
//   stale (counted, nothing sent).
// - A final acknowledgement carries received = all fragments and credit = window, also for an
//   abort status from the gateway or for the outcome timeout (0x83), as a node's would.
// - An outcome status the master cannot take as the end of its packet (in_progress, the
//   undefined 2..0x7F, or 0x85, which a sender ignores unless it has just aborted) is sent as
//   0x82 (the node could not take the packet): the master ends the packet at once instead of
//   waiting for its retries to run out.
// - A multi-fragment packet's buffer is reserved at its first fragment (up to kReserveBytes;
//   beyond, the vector grows by doubling) and moved out whole with the packet; an aborted
//   packet's buffer is cleared and kept. A one-frame packet (a plain RPDO) gets its own
//   8-byte vector. So no allocation per frame, one (rarely a few) per packet.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/pdop.hpp"

namespace canbridge::bridge {

// The relay's limits (surface configuration, `pdop:` block of the surface file).
struct RpdopRelayOptions {
  std::size_t max_packet_bytes = 4096;               // 1..524,280; larger: abort 0x81
  std::chrono::milliseconds fragment_timeout{200};   // 1 ms..10 s, as a node (section 4.3)
  std::uint8_t window = 4;                           // 1..255: the credit it grants
  std::chrono::milliseconds outcome_timeout{10000};  // 1 ms..600 s: forwarded, no outcome: 0x83
};
// Every problem of `options`, each "field: message" (empty when valid).
std::vector<std::string> validate(const RpdopRelayOptions& options);

class RpdopRelay {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  using NodeId = canopen::NodeId;

  // A complete packet from the master, to hand to the node's gateway.
  struct Packet {
    std::uint64_t request_id = 0;  // unique per relay, from 1; names the outcome later
    NodeId node = 0;               // surface node id 1..31
    unsigned rpdo = 0;             // 1..4
    std::vector<std::uint8_t> bytes;
  };
  // Appended to, never cleared here.
  struct Output {
    std::vector<can::Frame> frames;  // acknowledgements, to write to the surface bus in order
    std::vector<Packet> packets;     // complete packets, to forward
  };
  struct Counters {
    std::uint64_t packets = 0;           // forwarded
    std::uint64_t completed = 0;         // outcome complete, status 1 sent to the master
    std::uint64_t failed = 0;            // outcome an abort status, sent to the master
    std::uint64_t outcome_timeouts = 0;  // no outcome within outcome_timeout: 0x83 sent
    std::uint64_t stale_outcomes = 0;    // outcome for no forwarded packet (e.g. master aborted)
    std::uint64_t receiver_aborts = 0;   // own aborts: toggle, oversize, short, fragment timeout
    std::uint64_t sender_aborts = 0;     // abort frames from the master
    std::uint64_t ack_requests = 0;
    std::uint64_t dropped_fragments = 0;  // while resynchronising, or while forwarded
  };

  // Throws std::invalid_argument naming the first problem validate() finds.
  explicit RpdopRelay(RpdopRelayOptions options = {});

  // Which surface nodes the relay answers for (pdop nodes of connected gateways); none at first.
  // Turning a node off forgets its streams and its last finished packet silently (outcomes of
  // its forwarded packets become stale). Ids outside 1..31 are never relayed.
  void set_relayed(NodeId node, bool relayed);
  bool relayed(NodeId node) const;

  // Every frame read on the surface bus. Takes (returns true for) data frames on RPDO1..4 COB-IDs
  // (any t/c) of a relayed node, and remote frames on 0x680 + a relayed node; anything else
  // returns false, touching nothing. Timeouts up to `now` of that node are applied first.
  bool on_frame(const can::Frame& frame, TimePoint now, Output& out);

  // The gateway's outcome for `request_id`: `status` complete, or the abort status the master is
  // to see (0x80..0xFF). Sends the final acknowledgement; stale ids are counted and ignored.
  void on_outcome(std::uint64_t request_id, canopen::pdop::AckStatus status, Output& out);
  // Ends every forwarded packet of `node` (every node: 0) with `status` (e.g. the gateway's link
  // went down: 0x82), as if it were the outcome (counted as completed / failed likewise).
  void fail_forwarded(NodeId node, canopen::pdop::AckStatus status, Output& out);

  // Fragment and outcome timeouts up to `now`: a deadline equal to `now` has passed, so a timer
  // fired at next_deadline() finds it (docs/pdop.md section 3 rule 5). A fragment timeout sends
  // nothing (0x83 is the answer to a request, section 4.3); an outcome timeout sends 0x83.
  void tick(TimePoint now, Output& out);
  // The earliest fragment or outcome timeout; nullopt when no packet is received or forwarded.
  std::optional<TimePoint> next_deadline() const;

  const RpdopRelayOptions& options() const { return options_; }
  const Counters& counters() const { return counters_; }

 private:
  static constexpr std::size_t kRpdos = 4;
  static constexpr std::size_t kReserveBytes = std::size_t{64} * 1024;

  enum class Phase : std::uint8_t {
    idle,       // no packet: the next fragment must have t = 0
    receiving,  // fragments being taken; deadline = last fragment + fragment_timeout
    aborted,    // the relay aborted; fragments are dropped up to the next c = 0 frame (4.5)
    forwarded,  // last fragment taken, packet handed on; deadline = outcome_timeout
  };
  struct Stream {
    Phase phase = Phase::idle;
    bool expected_toggle = false;  // the t of the fragment numbered `received`
    std::uint16_t received = 0;    // fragments accepted (cannot wrap: at most 65,535)
    unsigned since_ack = 0;        // accepted since the last acknowledgement
    canopen::pdop::AckStatus abort_status = canopen::pdop::AckStatus::in_progress;
    TimePoint deadline{};
    std::uint64_t request_id = 0;  // forwarded: the packet's id
    std::vector<std::uint8_t> bytes;
  };

  Stream& stream(NodeId node, unsigned rpdo) { return streams_[(node - 1u) * kRpdos + rpdo - 1]; }
  const Stream& stream(NodeId node, unsigned rpdo) const {
    return streams_[(node - 1u) * kRpdos + rpdo - 1];
  }
  void expire(NodeId node, TimePoint now, Output& out);
  void on_fragment(NodeId node, unsigned rpdo, bool toggle, bool continued,
                   std::span<const std::uint8_t> data, TimePoint now, Output& out);
  void on_sender_abort(NodeId node, unsigned rpdo, Output& out);
  void abort_packet(NodeId node, unsigned rpdo, canopen::pdop::AckStatus status, bool continued,
                    Output& out);
  void forward(NodeId node, unsigned rpdo, std::vector<std::uint8_t> bytes, TimePoint now,
               Output& out);
  void end_forwarded(NodeId node, unsigned rpdo, canopen::pdop::AckStatus status, Output& out);
  void answer_request(NodeId node, Output& out);
  void finish(NodeId node, const canopen::pdop::Ack& ack, Output& out);
  void send(NodeId node, const canopen::pdop::Ack& ack, Output& out) const;
  canopen::pdop::Ack ack_of(NodeId node, unsigned rpdo, canopen::pdop::AckStatus status) const;

  RpdopRelayOptions options_;
  Counters counters_;
  std::uint64_t next_request_id_ = 1;
  std::array<bool, canopen::pdop::kMaxNode + 1> relayed_{};  // index = node id; [0] unused
  // Per node, the answer to a request when no packet of it is open (section 4.3).
  std::array<std::optional<canopen::pdop::Ack>, canopen::pdop::kMaxNode + 1> last_finished_{};
  std::array<Stream, canopen::pdop::kMaxNode * kRpdos> streams_{};
};

}  // namespace canbridge::bridge
