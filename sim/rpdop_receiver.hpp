// The node side of RPDOP (docs/pdop.md section 4): reassembles the PDO Packets the master sends
// to this node's RPDO1..4 and paces the master with acknowledgements. A pure core: frames and
// the time in, acknowledgements and finished packets out.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/pdop.hpp"
#include "sim/node_spec.hpp"

namespace canbridge::sim {

class RpdopReceiver {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  struct Packet {
    unsigned rpdo = 1;  // 1..4
    std::vector<std::uint8_t> bytes;
  };

  // Diagnostics, kept across reset(). Each receiver abort is counted once, by its reason.
  struct Counters {
    std::uint64_t packets = 0;  // completed, one-frame packets included
    std::uint64_t toggle_errors = 0;
    std::uint64_t oversize = 0;
    std::uint64_t timeouts = 0;
    std::uint64_t short_fragments = 0;
    std::uint64_t sender_aborts = 0;      // abort frames received, whatever was open
    std::uint64_t dropped_fragments = 0;  // dropped while resynchronising after a receiver abort
    std::uint64_t ack_requests = 0;
  };

  // Throws std::invalid_argument for a node id outside 1..31, max_packet_bytes outside
  // 1..524,280, fragment_timeout outside 1 ms..10 s or a window of 0.
  RpdopReceiver(canopen::NodeId node, const PdopSpec& spec);

  canopen::NodeId node_id() const { return node_; }
  // The node-id command of the fpga node (docs/nmt-node-id.md) arrives as a frame, so a bad id is
  // refused with false rather than thrown. A new id implies reset().
  bool set_node_id(canopen::NodeId node);

  // Any received frame. Returns false, touching nothing, unless it is a data frame on one of this
  // node's RPDO1..4 COB-IDs (any t/c: a fragment or a sender abort) or a remote frame on 0x680 +
  // node (an acknowledgement request, any DLC). Fragment timeouts up to `now` are applied first.
  // Acknowledgements are appended to `out`, a completed packet to `completed`.
  bool on_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out,
                std::vector<Packet>& completed);

  // Discards every packet whose fragment timeout has passed at `now`. Sends nothing: the master
  // learns status 0x83 when it asks (section 4.3).
  void poll(TimePoint now);
  // The earliest fragment timeout; TimePoint::max() when no packet is being received.
  TimePoint next_deadline() const;

  // NMT reset or leaving operational: discards partial packets silently and forgets the last
  // finished packet, as a node that has just started.
  void reset();

  const Counters& counters() const { return counters_; }

 private:
  enum class Phase : std::uint8_t {
    idle,       // no packet: the next fragment must have t = 0
    receiving,  // a packet is being received
    aborted,    // the node aborted the packet; fragments are dropped up to the next c = 0 frame
  };
  struct Stream {
    Phase phase = Phase::idle;
    std::vector<std::uint8_t> bytes;
    std::uint16_t received = 0;    // fragments accepted
    unsigned since_ack = 0;        // fragments accepted since the last acknowledgement
    bool expected_toggle = false;  // the t of the fragment numbered `received`
    canopen::pdop::AckStatus abort_status = canopen::pdop::AckStatus::in_progress;
    TimePoint deadline{};
  };

  void on_fragment(unsigned rpdo, bool toggle, bool continued, std::span<const std::uint8_t> data,
                   TimePoint now, std::vector<can::Frame>& out, std::vector<Packet>& completed);
  void on_sender_abort(unsigned rpdo, std::vector<can::Frame>& out);
  void abort_packet(unsigned rpdo, canopen::pdop::AckStatus status, bool continued,
                    std::vector<can::Frame>& out);
  void answer_ack_request(std::vector<can::Frame>& out);
  void send(const canopen::pdop::Ack& ack, std::vector<can::Frame>& out) const;
  void finish(const canopen::pdop::Ack& ack, std::vector<can::Frame>& out);
  canopen::pdop::Ack ack_of(unsigned rpdo, canopen::pdop::AckStatus status) const;
  Stream& stream(unsigned rpdo) { return streams_[rpdo - 1]; }
  const Stream& stream(unsigned rpdo) const { return streams_[rpdo - 1]; }

  canopen::NodeId node_;
  PdopSpec spec_;
  std::array<Stream, 4> streams_{};
  // Answers an acknowledgement request when no packet is open (section 4.3).
  std::optional<canopen::pdop::Ack> last_finished_;
  Counters counters_;
};

}  // namespace canbridge::sim
