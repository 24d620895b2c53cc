// The surface's PDO Packet work (docs/pdop.md) as a core without I/O: which gateway and module own
// each pdop node, the RPDOP relay toward them, the TPDOP packets and reports they send, and what
// each counts. Frames, payloads and the time in; fragments and acknowledgements for the surface
// bus and payloads for gateways out. The surface only carries them (and writes, monitors, logs).
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "bridge/surface_pdop.hpp"
#include "bridge/warn_once.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "canopen/pdop.hpp"
#include "routing/rpdop_relay.hpp"

namespace canbridge::bridge {

class SurfacePdopWork {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;
  using GatewayId = std::size_t;

  struct Counters {
    std::uint64_t packets = 0;  // TPDOP packets put on the bus (delivered())
    std::uint64_t packet_bytes = 0;
    std::uint64_t malformed = 0;  // bad node, TPDO, size or module: dropped
    std::uint64_t probable_repeats = 0;
    std::uint64_t discards = 0;         // broken packets the gateways reported
    std::uint64_t rpdop_forwarded = 0;  // the master's RPDOP packets sent to gateways
    std::uint64_t rpdop_complete = 0;   // ... acknowledged complete by the node
    std::uint64_t rpdop_failed = 0;     // ... any other outcome, or no link to send it on
  };

  // The gateway a message came from: its id, name (for the log) and the modules it announced.
  struct From {
    GatewayId id = 0;
    std::string_view name;
    std::span<const std::uint32_t> modules;
    // Whether the gateway's claims cover a surface node.
    std::function<bool(canopen::NodeId)> speaks_for;
  };

  // What flush() hands the surface: RPDOP packets for gateways (serialized v1::Payload, reliable,
  // in order) and the relay's acknowledgements for the surface bus.
  struct Output {
    std::vector<std::pair<GatewayId, std::string>> payloads;
    std::vector<can::Frame> frames;
  };

  explicit SurfacePdopWork(RpdopRelayOptions relay_options = {});

  // A gateway's list of its pdop nodes (first on every link): each node it may speak for is
  // owned by it from now on, relayed as whole packets or crossing as frames as it says.
  void on_nodes(const From& from, const v1::PdopNodes& nodes);
  // One TPDOP packet: what it comes to on the bus. Malformed ones are counted (warned once) here;
  // not_its_own is the caller's to count (per gateway). A packet the bus took: delivered().
  PdopPacketToBus on_packet(const From& from, const v1::PdopPacket& packet);
  void delivered(const From& from, const v1::PdopPacket& packet);
  // Discards and RPDOP outcomes a gateway reports: counted; each outcome answers its master.
  void on_reports(const From& from, const v1::PdopReports& reports);

  // A frame a master wrote on the surface bus: true when it is RPDOP to a relayed node (taken).
  bool on_bus_frame(const can::Frame& frame, TimePoint now);
  void tick(TimePoint now);
  std::optional<TimePoint> next_deadline() const { return relay_.next_deadline(); }
  // The relay's packets as payloads for their owners' gateways, answered at once with 0x82 (no
  // room) when that gateway's link is not up, and its acknowledgements. Valid until the next call.
  Output& flush(const std::function<bool(GatewayId)>& link_up);

  // RPDOP fragments to this node cross as frames (its gateway does not reassemble): in bus order,
  // never conflated.
  bool fragments_as_frames(canopen::NodeId surface_node) const {
    return fragments_as_frames_[surface_node & canopen::pdop::kMaxNode];
  }
  const RpdopRelay& relay() const { return relay_; }
  const Counters& counters() const { return counters_; }

 private:
  enum Warn : std::size_t { kMalformed, kDiscard, kRpdopFailed, kRepeat, kWarnKinds };
  struct Owner {
    std::optional<GatewayId> gateway;
    std::uint32_t module_id = 0;
  };

  bool announced(const From& from, std::uint32_t module_id) const;

  RpdopRelay relay_;
  RpdopRelay::Output relay_out_;
  Output out_;
  std::array<Owner, canopen::pdop::kMaxNode + 1> owner_{};  // by surface node id
  std::array<bool, canopen::pdop::kMaxNode + 1> fragments_as_frames_{};
  Counters counters_;
  WarnOnce<kWarnKinds> warn_;
};

}  // namespace canbridge::bridge
