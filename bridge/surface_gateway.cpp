#include "bridge/surface_gateway.hpp"

#include "bridge/frame_batch_codec.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

SurfaceGateway::SurfaceGateway(std::string gateway_name, Id gateway_id,
                               const BackboneTuning& tuning, Events surface_events)
    : name(std::move(gateway_name)),
      id(gateway_id),
      outbox(tuning.outbox),
      events(std::move(surface_events)),
      stream(tuning.session, backbone::PeerStream::Handlers{
                                 [this](backbone::PayloadSink& sink) { produce(sink); },
                                 [this](std::span<const std::uint8_t> payload, bool) {
                                   events.payload(*this, payload);
                                 },
                                 [this](const v1::Hello& peer) {
                                   outbox.set_head_runs(peer.protocol_minor() >= kHeadRunsMinor);
                                   events.up(*this);
                                 },
                                 [this] { events.down(*this); },
                                 // A new gateway process: nothing queued for the old one goes.
                                 [this](const v1::Hello&) {
                                   outbox.discard_queued();
                                   discard_queued_remote_payloads();
                                   events.restarted(*this);
                                 },
                                 [this](const std::string& payload, backbone::ReliableDrop why) {
                                   events.payload_dropped(payload, why);
                                 }}) {
  outbox.on_discard([this](std::uint32_t, const can::Frame& frame, FrameOutbox::Discard why) {
    events.frame_dropped(frame, why == FrameOutbox::Discard::too_old
                                    ? backbone::ReliableDrop::too_old
                                    : backbone::ReliableDrop::peer_restart);
  });
}

void SurfaceGateway::discard_queued_remote_payloads() {
  std::erase_if(rpdop_out, [](const std::string& payload) {
    v1::Payload parsed;
    return parsed.ParseFromString(payload) &&
           (parsed.has_remote_request() || parsed.has_remote_cancel());
  });
}

void SurfaceGateway::produce(backbone::PayloadSink& sink) {
  while (!rpdop_out.empty()) {
    if (sink.room() == 0 || !sink.reliable_room(rpdop_out.front().size())) break;
    sink.send_reliable(std::move(rpdop_out.front()));
    rpdop_out.pop_front();
  }
  outbox.produce(sink);
}

}  // namespace canbridge::bridge
