// The gateway's PDO Packet work (docs/pdop.md) as a core without I/O: module bus frames and
// RPDOP packets from the surface in, fragments for the module buses and payloads for the surface
// out, every time injected. The gateway only carries frames and payloads to and from it.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "bridge/warn_once.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"
#include "routing/pdop_reassembler.hpp"
#include "routing/pdop_segmenter.hpp"

namespace canbridge::backbone {
class PayloadSink;
}

namespace canbridge::bridge {

class GatewayPdopWork {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // One per module of the gateway, in the map's order; only pdop modules with `reassemble` on
  // get a reassembler and a segmenter (the others' fragments cross as frames).
  struct Module {
    ModuleId id = 0;
    bool reassemble = true;
    PdopReassemblerOptions reassembly{};
    PdopSegmenterOptions segmentation{};
  };

  // Bytes of TPDOP packets and reports waiting for the link: a link down for long refuses new
  // ones (counted) rather than grow without bound; queued ones are never dropped.
  static constexpr std::size_t kDefaultMaxQueuedBytes = std::size_t{8} << 20;
  // Packets are batched into one payload up to this size while the link is behind.
  static constexpr std::size_t kBatchBytes = 2048;

  struct Counters {
    std::uint64_t packets = 0;         // TPDOP packets queued for the surface
    std::uint64_t packet_bytes = 0;    // ... their data bytes
    std::uint64_t fragments = 0;       // ... their fragments (frames not sent one by one)
    std::uint64_t discards = 0;        // broken TPDOP packets, reported to the surface
    std::uint64_t refused = 0;         // packets or reports refused: the queue was full
    std::uint64_t rpdop_packets = 0;   // RPDOP packets from the surface
    std::uint64_t rpdop_complete = 0;  // ... the node acknowledged them complete
    std::uint64_t rpdop_failed = 0;    // ... any other outcome
  };

  // Fragments for one module bus, to be written whole and in order.
  struct BusFrames {
    std::size_t module_index = 0;
    std::vector<can::Frame> frames;
  };

  // `map` is the gateway's live map (renamed nodes move in it); it must outlive the core.
  // `log_name` prefixes the few log lines (first of each kind, failed RPDOP outcomes).
  GatewayPdopWork(const NodeMap& map, std::vector<Module> modules, std::string log_name,
                  std::size_t max_queued_bytes = kDefaultMaxQueuedBytes);
  ~GatewayPdopWork();

  // Some module has the pdop profile: the surface learns its nodes (PdopNodes) on every link.
  bool active() const { return active_; }
  bool reassembles(std::size_t module_index) const;

  // A frame read on module `module_index`'s bus at `now`; `unix_offset` (Unix time minus steady
  // time) dates the packets. True when the frame was PDOP traffic the core took (a TPDOP
  // fragment or a node's RPDOP acknowledgement); false: it goes on to the translator.
  bool on_bus_frame(std::size_t module_index, const can::Frame& frame, TimePoint now,
                    std::chrono::nanoseconds unix_offset);
  // A node table event of the same bus, in bus order: a node that booted or took another id has
  // no packet open in either direction.
  void on_node_event(const NodeEvent& event, TimePoint now);
  // RPDOP packets from the surface: segmented toward their nodes, or refused with an outcome.
  void on_rpdop_packets(const v1::PdopPackets& packets, TimePoint now);
  // Timeouts up to `now`, every reassembler and segmenter.
  void tick(TimePoint now, std::chrono::nanoseconds unix_offset);
  // The earliest deadline of every reassembler and segmenter; nullopt when none waits on time.
  std::optional<TimePoint> next_deadline() const;

  // A (new) surface must learn the pdop nodes: PdopNodes goes out ahead of everything queued.
  void announce_nodes();

  // Fragments for the buses since the last take, in the order they were made.
  std::vector<BusFrames>& bus_frames() { return bus_out_; }

  // Payloads for the surface, oldest first (PdopPackets, PdopReports or PdopNodes): the next one
  // to send, nullptr when none. Reliable and in order; the gateway sends it, then pops it.
  const v1::Payload* next_payload();
  void pop_payload();
  // The next payload can never be sent (larger than the resend buffer): dropped and counted.
  void refuse_payload(std::size_t serialized_bytes);
  // Hands `sink` the payloads above while it has room, reliable and in order; one larger than
  // `max_reliable_bytes` (the resend buffer, which would never take it) is refused instead of
  // blocking the rest.
  void produce(backbone::PayloadSink& sink, std::size_t max_reliable_bytes);
  std::size_t queued_bytes() const { return out_bytes_; }
  std::size_t queued_payloads() const { return out_.size(); }

  const Counters& counters() const { return counters_; }
  // TPDOP frames the reassemblers dropped (offending or while resynchronising), all modules.
  std::uint64_t dropped_frames() const;

 private:
  class Sink;
  struct PdopModule {
    std::unique_ptr<PdopReassembler> reassembler;
    std::unique_ptr<PdopSegmenter> segmenter;
  };
  struct Queued {
    v1::Payload payload;  // PdopPackets, PdopReports or PdopNodes
    std::size_t bytes;    // estimate of the serialized size, for the bound and batching
  };
  enum Warn : std::size_t { kRefused, kDiscard, kRpdopUnknown, kWarnKinds };

  // Moves the segmenter's frames to bus_out_ and its outcomes to the report queue.
  void flush_segmenter(std::size_t module_index);
  // A new RPDOP outcome in the report queue; nullptr when the queue is full (counted).
  v1::RpdopOutcome* add_outcome_report();
  // Appends to the newest queued payload of `kind` while it is small (batches small packets
  // when the link is slower than the bus), else queues a new one. nullptr when the queue is full.
  v1::Payload* payload_for(v1::Payload::BodyCase kind, std::size_t adding_bytes);
  void queue_nodes();

  const NodeMap& map_;
  std::vector<Module> modules_;
  std::string log_name_;
  std::size_t max_queued_bytes_;
  std::vector<PdopModule> pdop_;  // per module, same order
  bool active_ = false;
  bool announce_ = false;
  PdopSegmenter::Output segmenter_out_;
  std::vector<BusFrames> bus_out_;
  std::deque<Queued> out_;  // oldest first
  std::size_t out_bytes_ = 0;
  Counters counters_;
  WarnOnce<kWarnKinds> warn_;
};

}  // namespace canbridge::bridge
