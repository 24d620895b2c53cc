// TPDOP reassembly on the gateway (docs/pdop.md sections 1-3, 5; issue 6): the fragments that the
// nodes of one `pdop` module bus send on their TPDO1..4 in, whole packets and reports of broken
// ones out. Pure: frames and the steady-clock time in, results to a Sink; no sockets, no timers,
// no logging. One reassembler per pdop module. The gateway arms one timer at next_deadline() and
// calls tick() when it fires (like NodeTable).
//
// One reassembly per (local node 1..31, TPDO 1..4), each the receiver of docs/pdop.md section 3;
// the 124 streams are independent, so fragments of different nodes and TPDOs interleave freely.
// A stream is idle, assembling a packet, or resynchronising: after any error it drops every frame
// up to and including the next c = 0 frame (the offending frame counts: with c = 0 it is the
// end), and the frame after that starts a packet. A broken packet is never delivered.
//
// What one toggle bit can and cannot detect. A fragment's only sequence information is t, the
// fragment index mod 2, and c, "more follow". Of a packet's fragments 0..n-1:
//
//   Detected: the partial packet is discarded and reported.
//   - A run of an odd number of consecutive lost fragments that leaves the packet's last fragment:
//     the fragment after the run carries the wrong toggle (missing_fragment). When the run starts
//     at fragment 0, that fragment has t = 1 and arrives while the stream is idle (the doc's
//     "missing first fragment", missing_fragment with 0 fragments).
//   - A fragment repeated right after itself (CAN's double reception), unless it is a last
//     fragment with t = 0, see below: the repeat carries the toggle just seen (duplicate). A
//     repeated last fragment with t = 1 (an even number of fragments) arrives while the stream
//     is idle: reported as a duplicate with 0 fragments; the packet itself was delivered intact.
//   - The last fragment(s) lost while an odd number of fragments was accepted: the next packet's
//     first fragment (t = 0) carries the wrong toggle. It is the offending frame: the stream
//     resynchronises through that whole next packet, which is lost too, without a report of its
//     own (counted in dropped_frames).
//   - Any loss followed by a silence of fragment_timeout or more on the stream (timeout), any
//     packet growing past max_packet_bytes (oversize), a fragment with c = 1 and fewer than 8
//     bytes (short_fragment), a zero-length data frame with c = 0 (empty_frame).
//
//   Not detectable (docs/pdop.md does not list these):
//   - A run of an even number of consecutive lost fragments strictly inside a packet: the
//     packet is delivered without those 16 x k bytes.
//   - A run of an even number of lost fragments from fragment 0 (not the last): the rest, from a
//     fragment with t = 0, is delivered as a packet of its own (a suffix of the real one).
//   - The last fragment(s) lost while an even number of fragments was accepted, and the node's
//     next packet on that TPDO starting within fragment_timeout: both are delivered as one packet
//     (unless it grows past max_packet_bytes). fragment_timeout only separates packets when the
//     node's gap between packets is at least that long.
//   - A repeated last fragment with t = 0 (an odd number of fragments): the repeat is a valid
//     one-frame packet and is delivered as one (1..8 bytes).
//   - A fragment repeated after the next one (k, k+1, k again): the toggles still alternate. On
//     one CAN bus a controller retransmits a frame before it sends the next, so this takes
//     reordering (several transmit mailboxes).
//   - A whole packet lost, e.g. a one-frame packet: nothing of it arrives.
//   duplicate versus missing_fragment is a best guess, the discard itself is certain: a
//   toggle error whose frame repeats the stream's last accepted fragment exactly (t, c, length,
//   data; after a delivery, that packet's last fragment) is called a duplicate, any other one a
//   missing fragment. A lost fragment followed by one with the same c and bytes as the one before
//   the loss is misnamed a duplicate. docs/pdop.md calls both `toggle`.
//
// A one-frame packet (t = c = 0, 1..8 bytes) is a plain TPDO (docs/pdop.md section 1): it is
// delivered as a packet with fragments == 1, so the gateway may forward it as a PDO frame.
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

// docs/pdop.md section 5, the TPDOP receiver's (gateway, per module) limits.
struct PdopReassemblerOptions {
  static constexpr std::size_t kDefaultMaxPacketBytes = 4096;
  static constexpr std::chrono::milliseconds kDefaultFragmentTimeout{100};
  static constexpr std::chrono::milliseconds kMinFragmentTimeout{1};
  static constexpr std::chrono::milliseconds kMaxFragmentTimeout{10000};

  // 1..canopen::pdop::kMaxPacketBytes (524,280).
  std::size_t max_packet_bytes = kDefaultMaxPacketBytes;
  // 1 ms..10 s. A fragment arriving at the last accepted one's time + fragment_timeout or later
  // is late (section 3 rule 5).
  std::chrono::milliseconds fragment_timeout = kDefaultFragmentTimeout;

  // nullopt when valid, else what is wrong, naming the field, e.g.
  // "max_packet_bytes: 0 is outside 1..524280". For the configuration check at startup.
  std::optional<std::string> validate() const;
};

class PdopReassembler {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;
  using NodeId = canopen::NodeId;

  static constexpr NodeId kMaxNode = canopen::pdop::kMaxNode;  // 31
  static constexpr unsigned kTpdoCount = 4;
  static constexpr std::size_t kStreamCount = std::size_t{kMaxNode} * kTpdoCount;  // 124

  // A complete packet. `data` points into the reassembler's buffer (into the frame for a
  // one-frame packet) and is valid only during the Sink call: copy what you keep.
  struct Packet {
    NodeId node = 0;                     // local node id on the module bus, 1..31
    unsigned tpdo = 0;                   // 1..4
    std::span<const std::uint8_t> data;  // 1..max_packet_bytes bytes
    std::uint32_t fragments = 0;         // ceil(data.size() / 8); 1: a plain TPDO
    TimePoint first{};                   // time of the first fragment
    TimePoint last{};                    // time of the last fragment
    // A one-frame packet equal to the last fragment (t = 0) of the stream's previous,
    // multi-fragment packet, within kRepeatWindow of it: probably CAN's double reception of that
    // fragment rather than a packet (docs/pdop.md section 7). Delivered all the same: a
    // receiver cannot tell, so it is flagged for whoever consumes packets.
    bool probable_repeat = false;
  };
  // Double reception repeats a frame right after the error frame that caused it: two frame
  // times at 125 kbit/s.
  static constexpr std::chrono::milliseconds kRepeatWindow{2};

  enum class Reason : std::uint8_t {
    missing_fragment,  // toggle error (or t = 1 while idle) not explained as a repeat
    duplicate,         // toggle error by a repeat of the last accepted fragment
    timeout,           // fragment_timeout or more since the last accepted fragment
    oversize,          // would grow past max_packet_bytes
    short_fragment,    // c = 1 with fewer than 8 bytes
    empty_frame,       // zero-length data frame with c = 0: a protocol error in TPDOP (section 2)
    node_restart,      // on_node_restart(): the node booted with a packet open
    frames_lost,       // on_frames_lost(): the bus lost frames (receive queue overflow)
  };
  static constexpr std::size_t kReasonCount = 8;
  // A frame that breaks several rules is reported by the first of: timeout, empty_frame, the
  // toggle (missing_fragment or duplicate), short_fragment, oversize. docs/pdop.md gives no order.

  // A discarded packet, or (fragments == 0) a frame refused while no packet was open.
  struct Discard {
    NodeId node = 0;
    unsigned tpdo = 0;
    Reason reason = Reason::missing_fragment;
    std::uint32_t fragments = 0;  // accepted before the error
    std::size_t bytes = 0;        // their bytes
    TimePoint first{};            // first accepted fragment (== at when fragments == 0)
    TimePoint last{};             // last accepted fragment (== at when fragments == 0)
    TimePoint at{};               // when the error was seen (tick's now for a timer timeout)
    friend bool operator==(const Discard&, const Discard&) = default;
  };

  class Sink {
   public:
    virtual ~Sink() = default;
    virtual void on_packet(const Packet& packet) = 0;
    virtual void on_discard(const Discard& discard) = 0;
  };

  // Kept for the life of the reassembler. Every TPDOP frame taken is, exactly once, part of a
  // delivered packet, part of a discarded one, dropped, or still pending:
  //   frames == packet_fragments + discarded_fragments + dropped_frames + pending_fragments().
  struct Counters {
    std::uint64_t frames = 0;  // data frames taken (on_frame returned true)
    std::uint64_t packets = 0;
    std::uint64_t single_frame_packets = 0;  // of which one-frame packets (plain TPDOs)
    std::uint64_t probable_repeats = 0;      // of which flagged probable_repeat
    std::uint64_t packet_bytes = 0;
    std::uint64_t packet_fragments = 0;
    std::array<std::uint64_t, kReasonCount> discards{};  // by Reason
    std::uint64_t discarded_fragments = 0;               // accepted into a packet later discarded
    std::uint64_t discarded_bytes = 0;
    // Offending frames and frames dropped while resynchronising.
    std::uint64_t dropped_frames = 0;

    std::uint64_t discarded(Reason reason) const {
      return discards[static_cast<std::size_t>(reason)];
    }
    std::uint64_t discards_total() const;
  };

  enum class State : std::uint8_t { idle, assembling, resynchronising };

  // Throws std::invalid_argument with validate()'s text when the options are invalid.
  PdopReassembler();
  explicit PdopReassembler(const PdopReassemblerOptions& options);

  // Every frame read on the module bus. Takes (returns true for) standard data frames on a TPDO
  // COB-ID of node 1..31 with any t/c, i.e. 0x181..0x1FF, 0x281..0x2FF, 0x381..0x3FF,
  // 0x481..0x4FF without node 0; anything else (remote, extended, error frames, other COB-IDs)
  // returns false at the cost of a few compares, touching nothing. First applies this stream's
  // fragment timeout at `now` (other streams' are tick()'s): a late fragment is reported as
  // that packet's timeout and dropped. Calls the sink at most once. Allocates nothing for one-frame
  // packets, and nothing for longer ones once the stream's buffer has grown to the size of its
  // packets.
  bool on_frame(const can::Frame& frame, TimePoint now, Sink& sink);

  // Reports (timeout) every packet whose deadline is at or before `now`, by node, then TPDO, and
  // resynchronises those streams.
  void tick(TimePoint now, Sink& sink);
  // The earliest deadline of the packets being assembled (last fragment + fragment_timeout);
  // nullopt when none is. A tick() at that time finds it passed. Costs one compare per packet
  // being assembled.
  std::optional<TimePoint> next_deadline() const;

  // The node booted (boot-up seen by the gateway): its next fragments start new packets. Open
  // packets of the node are discarded (node_restart; timeout when already past the deadline);
  // resynchronisation ends.
  void on_node_restart(NodeId node, TimePoint now, Sink& sink);

  // Frames of the bus were lost (can::Frame::follows_loss: a receive queue overflowed), so any
  // stream may have lost fragments, an even number of them undetectably (docs/pdop.md section 7).
  // Every open packet is discarded (frames_lost; timeout when already late) and every stream
  // resynchronises to its next c = 0 frame, idle ones too: a packet whose first two fragments
  // were lost would otherwise be delivered as a suffix. The cost: each stream's next packet.
  void on_frames_lost(TimePoint now, Sink& sink);

  const PdopReassemblerOptions& options() const { return options_; }
  const Counters& counters() const { return counters_; }
  State state(NodeId node, unsigned tpdo) const;  // idle for a node or TPDO out of range
  std::size_t assembling() const;                 // packets being assembled
  std::uint64_t pending_fragments() const;        // accepted into the packets being assembled
  // Memory held for packet bytes: at most kStreamCount x max_packet_bytes, whatever the input.
  std::size_t buffer_capacity() const;

 private:
  struct Stream {
    State state = State::idle;
    bool expected_toggle = false;
    std::uint32_t fragments = 0;
    TimePoint first{};
    TimePoint last{};
    TimePoint deadline{};
    std::vector<std::uint8_t> bytes;
    // The last accepted fragment, for telling a repeat from a loss. Kept after a delivery (a
    // repeated last fragment arrives while idle), cleared by a discard.
    bool has_previous = false;
    bool previous_toggle = false;
    bool previous_continued = false;
    std::uint8_t previous_length = 0;
    std::array<std::uint8_t, canopen::pdop::kFragmentBytes> previous{};
    std::uint32_t previous_packet_fragments = 0;  // of the last packet delivered
  };

  void on_fragment(std::size_t index, bool toggle, bool continued,
                   std::span<const std::uint8_t> data, TimePoint now, Sink& sink);
  void accept(std::size_t index, bool toggle, bool continued, std::span<const std::uint8_t> data,
              TimePoint now, Sink& sink);
  static void remember(Stream& s, bool toggle, bool continued, std::span<const std::uint8_t> data);
  void deliver(std::size_t index, std::span<const std::uint8_t> data, std::uint32_t fragments,
               TimePoint first, TimePoint last, Sink& sink, bool probable_repeat = false);
  static bool repeats_previous(const Stream& s, bool toggle, bool continued,
                               std::span<const std::uint8_t> data);
  // Reports and discards the stream's packet (if any). With `offending` a frame is refused: it
  // is counted dropped, and the stream resynchronises when it has `continued`, else is idle.
  // Without, the stream resynchronises (timer timeout).
  void fail(std::size_t index, Reason reason, TimePoint now, Sink& sink, bool offending,
            bool continued);
  void set_assembling(std::size_t index, bool on);

  PdopReassemblerOptions options_;
  Clock::duration timeout_;
  std::array<Stream, kStreamCount> streams_{};  // index (node - 1) * 4 + (tpdo - 1)
  std::array<std::uint64_t, 2> assembling_{};   // bit per stream index: State::assembling
  Counters counters_;
};

const char* to_string(PdopReassembler::Reason reason);
// "node 5 TPDO2: packet discarded (missing_fragment) after 3 fragments, 24 bytes": for logs.
std::string to_string(const PdopReassembler::Discard& discard);

}  // namespace canbridge::bridge
