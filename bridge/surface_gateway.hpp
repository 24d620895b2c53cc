// One gateway as the surface knows it, kept across its links so reliable streams resume: the
// frames queued for it, the surface's own reliable payloads for it (RPDOP packets, remote
// requests and cancels), its session stream, and what it sent that was not its to send.
#pragma once

#include <array>
#include <bitset>
#include <cstdint>
#include <deque>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/backbone_tuning.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/gateway_table.hpp"
#include "bridge/line_loss_counter.hpp"

namespace canbridge::bridge {

struct SurfaceGateway {
  using Id = GatewayTable::GatewayId;
  // What the surface does when the gateway's stream reports; each after the gateway's own part.
  struct Events {
    std::function<void(SurfaceGateway&, std::span<const std::uint8_t> payload)> payload;
    std::function<void(SurfaceGateway&)> up;    // a link to it is ready
    std::function<void(SurfaceGateway&)> down;  // that link is gone
    // A new gateway process: what was queued for the old one is discarded already.
    std::function<void(SurfaceGateway&)> restarted;
    std::function<void(const std::string& payload, backbone::ReliableDrop why)> payload_dropped;
    std::function<void(const can::Frame& frame, backbone::ReliableDrop why)> frame_dropped;
  };

  SurfaceGateway(std::string gateway_name, Id gateway_id, const BackboneTuning& tuning,
                 Events events);
  // The stream's handlers point here: never moved.
  SurfaceGateway(const SurfaceGateway&) = delete;
  SurfaceGateway& operator=(const SurfaceGateway&) = delete;

  // Remote requests and cancels queued for the old process (its link went down before they
  // left) are not the new one's: it would run a request the surface has given up, seconds late.
  // The surface's remote access ends them (bridge/remote_request_ledger.hpp).
  void discard_queued_remote_payloads();
  // RPDOP packets and remote payloads first (the master waits on each), then frames.
  void produce(backbone::PayloadSink& sink);

  std::string name;
  Id id;
  std::vector<std::uint32_t> modules;  // as announced in its latest accepted hello
  FrameOutbox outbox;
  // Serialized reliable payloads of the surface's own: PdopPackets, remote requests and cancels.
  std::deque<std::string> rpdop_out;
  Events events;
  backbone::PeerStream stream;
  LineLossCounter line_loss;
  // Frames it sent that were not its to send, by NotItsOwn; which reasons were warned already.
  std::array<std::uint64_t, kNotItsOwnReasons> not_its_own{};
  std::bitset<kNotItsOwnReasons> warned_not_its_own;
};

}  // namespace canbridge::bridge
