// A role's statistics as one typed snapshot (buses, backbone, drops by reason, nodes) and the rates
// between two snapshots: the pure core behind the periodic line, `canbridge stats` and /metrics.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "can/bus.hpp"

namespace canbridge::bridge {

// One CAN interface of the role.
struct BusStatistics {
  std::uint32_t module = 0;  // the module id on a gateway; 0 for the surface's bus
  std::string interface;     // "vcan0"
  can::BusCounters counters;
  bool link_up = true;  // false while the interface is down or gone (the bus reopens it)
};

// The backbone: links to the peer(s), bytes and frames carried, reliability.
struct BackboneStatistics {
  std::uint32_t peers_up = 0;  // gateway: 0 or 1 (the surface); surface: gateways bound now
  std::uint32_t peers_known = 0;
  std::uint64_t links = 0;  // links that completed the hello exchange, all so far
  std::uint64_t dead_links = 0;
  std::uint64_t tx_bytes = 0;
  std::uint64_t rx_bytes = 0;
  std::uint64_t tx_writes = 0;    // completed link writes (each one or more messages)
  std::uint64_t rx_messages = 0;  // backbone messages (envelopes) read
  std::uint64_t frames_sent = 0;  // CAN frames carried to the peer(s)
  std::uint64_t frames_received = 0;
  std::uint64_t batches_sent = 0;  // payloads of frames (FrameBatch messages) sent
  std::uint64_t reliable_sent = 0;
  std::uint64_t reliable_resent = 0;
  std::uint64_t resend_requests = 0;
  std::uint64_t unacked = 0;  // reliable payloads not yet acknowledged, now
  // Smoothed time from sending a reliable payload to its acknowledgement (ack delay included);
  // unset until one was measured on the current link.
  std::optional<std::chrono::microseconds> round_trip;
};

// A counted drop under its reason ("untranslatable-unknown-node", "bus-refused-...").
struct DropCount {
  std::string reason;
  std::uint64_t count = 0;
};

// What became of the SDO requests of the masters on the surface bus across link cuts (the
// surface only; docs/canopen-bridging.md, "What each request comes to across a cut").
struct SdoOutcomeCount {
  std::string outcome;
  std::uint64_t count = 0;
};

struct NodeSummary {
  std::uint64_t operational = 0;
  std::uint64_t pre_operational = 0;
  std::uint64_t stopped = 0;
  std::uint64_t in_loader = 0;
  std::uint64_t lost = 0;
  std::uint64_t unknown = 0;  // alive (answers SDO), state never reported (NodeRecord::state)
  std::uint64_t total() const {
    return operational + pre_operational + stopped + in_loader + lost + unknown;
  }
};

struct RoleStatistics {
  std::string role;  // "gateway" or "surface"
  std::string name;
  std::vector<BusStatistics> buses;
  BackboneStatistics backbone;
  std::vector<DropCount> drops;  // every reason, zero ones included: a stable set of names
  std::vector<SdoOutcomeCount> sdo_requests;  // every outcome, zeros included; empty: gateway
  NodeSummary nodes;
  std::uint64_t drops_total() const;
};

struct BusRates {
  double rx_frames = 0;  // per second
  double tx_frames = 0;
};

struct RoleRates {
  double seconds = 0;           // the window the rates cover; 0: no window yet (all rates 0)
  std::vector<BusRates> buses;  // in RoleStatistics::buses order
  double backbone_tx_bytes = 0;
  double backbone_rx_bytes = 0;
  double backbone_frames_sent = 0;
  double backbone_frames_received = 0;
  // Frames per frame-batch message sent in the window (0 when none was sent).
  double frames_per_message = 0;
  double drops = 0;
};

// The rates from `before` to `after`, `elapsed` apart. Buses are matched by position (the set
// of buses is fixed for a process); a counter that went backwards counts as 0.
RoleRates rates_between(const RoleStatistics& before, const RoleStatistics& after,
                        std::chrono::nanoseconds elapsed);

// Keeps the snapshot of the last sample and the one before it, so rates always cover a whole
// sampling interval, whenever they are asked for. The clock is injected (tests).
class RateMeter {
 public:
  using Clock = std::function<std::chrono::steady_clock::time_point()>;
  explicit RateMeter(Clock clock = [] { return std::chrono::steady_clock::now(); })
      : clock_(std::move(clock)) {}

  // Takes a sample (call once per interval, e.g. every second).
  void sample(RoleStatistics snapshot);
  // The rates over the last whole interval; seconds 0 until two samples were taken.
  RoleRates rates() const;

 private:
  struct Sample {
    std::chrono::steady_clock::time_point at;
    RoleStatistics snapshot;
  };
  Clock clock_;
  std::optional<Sample> previous_;
  std::optional<Sample> latest_;
};

}  // namespace canbridge::bridge
