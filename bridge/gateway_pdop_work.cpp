#include "bridge/gateway_pdop_work.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <limits>
#include <utility>

#include "backbone/peer_stream.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "canopen/pdop.hpp"

namespace canbridge::bridge {

namespace {
v1::PdopDiscard::Reason to_proto(PdopReassembler::Reason reason) {
  using R = PdopReassembler::Reason;
  switch (reason) {
    case R::missing_fragment:
      return v1::PdopDiscard::MISSING_FRAGMENT;
    case R::duplicate:
      return v1::PdopDiscard::DUPLICATE;
    case R::timeout:
      return v1::PdopDiscard::TIMEOUT;
    case R::oversize:
      return v1::PdopDiscard::OVERSIZE;
    case R::short_fragment:
      return v1::PdopDiscard::SHORT_FRAGMENT;
    case R::empty_frame:
      return v1::PdopDiscard::EMPTY_FRAME;
    case R::node_restart:
      return v1::PdopDiscard::NODE_RESTART;
    case R::frames_lost:
      return v1::PdopDiscard::FRAMES_LOST;
  }
  return v1::PdopDiscard::REASON_UNSPECIFIED;
}

v1::RpdopOutcome::Result to_proto(PdopResult result) {
  switch (result) {
    case PdopResult::complete:
      return v1::RpdopOutcome::COMPLETE;
    case PdopResult::receiver_abort:
      return v1::RpdopOutcome::RECEIVER_ABORT;
    case PdopResult::timeout:
      return v1::RpdopOutcome::TIMEOUT;
    case PdopResult::cancelled:
      return v1::RpdopOutcome::CANCELLED;
    case PdopResult::refused_busy:
      return v1::RpdopOutcome::REFUSED_BUSY;
    case PdopResult::refused_size:
      return v1::RpdopOutcome::REFUSED_SIZE;
    case PdopResult::refused_address:
      return v1::RpdopOutcome::REFUSED_ADDRESS;
  }
  return v1::RpdopOutcome::RESULT_UNSPECIFIED;
}

std::int64_t unix_us(std::chrono::nanoseconds since_epoch) {
  return std::chrono::duration_cast<std::chrono::microseconds>(since_epoch).count();
}

// Kernel receive time of `frame` (Unix) on the steady clock; `now` when it has none, or when the
// wall clock moved: fragment gaps are measured as they were on the bus, not as the reader loop
// happened to see them.
PdopReassembler::TimePoint steady_time_of(const can::Frame& frame, PdopReassembler::TimePoint now,
                                          std::chrono::nanoseconds unix_offset) {
  if (frame.timestamp.count() == 0) return now;
  const auto at = PdopReassembler::TimePoint(
      std::chrono::duration_cast<PdopReassembler::Clock::duration>(frame.timestamp - unix_offset));
  return at <= now && now - at < std::chrono::seconds(1) ? at : now;
}
}  // namespace

// Reassembled packets and discards of one module, into the surface queue.
class GatewayPdopWork::Sink final : public PdopReassembler::Sink {
 public:
  Sink(GatewayPdopWork& work, std::size_t module_index, std::chrono::nanoseconds unix_offset)
      : work_(work), module_index_(module_index), unix_offset_(unix_offset) {}

  void on_packet(const PdopReassembler::Packet& packet) override {
    GatewayPdopWork& w = work_;
    const std::size_t bytes = packet.data.size() + 24;
    v1::Payload* payload = w.payload_for(v1::Payload::kPdopPackets, bytes);
    if (!payload) return;
    v1::PdopPacket& p = *payload->mutable_pdop_packets()->add_packets();
    p.set_module_id(w.modules_[module_index_].id);
    p.set_local_node(packet.node);
    p.set_surface_node(w.map_.surface_of(module_index_, packet.node));
    p.set_pdo(packet.tpdo);
    p.set_data(packet.data.data(), packet.data.size());
    p.set_first_fragment_us(unix_us(unix_offset_ + packet.first.time_since_epoch()));
    p.set_duration_us(static_cast<std::uint32_t>(std::min<std::int64_t>(
        std::chrono::duration_cast<std::chrono::microseconds>(packet.last - packet.first).count(),
        std::numeric_limits<std::uint32_t>::max())));
    p.set_probable_repeat(packet.probable_repeat);
    ++w.counters_.packets;
    w.counters_.packet_bytes += packet.data.size();
    w.counters_.fragments += packet.fragments;
  }

  void on_discard(const PdopReassembler::Discard& discard) override {
    GatewayPdopWork& w = work_;
    ++w.counters_.discards;
    w.warn_.warn(Warn::kDiscard,
                 "gateway {}: module {} {}: reported to the surface (counted; later ones only in "
                 "the counters)",
                 w.log_name_, w.modules_[module_index_].id, to_string(discard));
    v1::Payload* payload = w.payload_for(v1::Payload::kPdopReports, 24);
    if (!payload) return;
    v1::PdopDiscard& d = *payload->mutable_pdop_reports()->add_discards();
    d.set_module_id(w.modules_[module_index_].id);
    d.set_local_node(discard.node);
    d.set_surface_node(w.map_.surface_of(module_index_, discard.node));
    d.set_tpdo(discard.tpdo);
    d.set_reason(to_proto(discard.reason));
    d.set_fragments(discard.fragments);
    d.set_bytes(static_cast<std::uint32_t>(discard.bytes));
  }

 private:
  GatewayPdopWork& work_;
  std::size_t module_index_;
  std::chrono::nanoseconds unix_offset_;  // steady clock -> Unix time, for the timestamps
};

GatewayPdopWork::GatewayPdopWork(const NodeMap& map, std::vector<Module> modules,
                                 std::string log_name, std::size_t max_queued_bytes)
    : map_(map),
      modules_(std::move(modules)),
      log_name_(std::move(log_name)),
      max_queued_bytes_(max_queued_bytes) {
  pdop_.resize(modules_.size());
  for (std::size_t m = 0; m < modules_.size() && m < map_.modules().size(); ++m) {
    if (map_.modules()[m].profile != IdProfile::pdop) continue;
    active_ = true;
    if (!modules_[m].reassemble) continue;
    pdop_[m].reassembler = std::make_unique<PdopReassembler>(modules_[m].reassembly);
    pdop_[m].segmenter = std::make_unique<PdopSegmenter>(modules_[m].segmentation);
  }
}

GatewayPdopWork::~GatewayPdopWork() = default;

bool GatewayPdopWork::reassembles(std::size_t m) const {
  return m < pdop_.size() && pdop_[m].reassembler != nullptr;
}

bool GatewayPdopWork::on_bus_frame(std::size_t m, const can::Frame& frame, TimePoint now,
                                   std::chrono::nanoseconds unix_offset) {
  if (!reassembles(m)) return false;
  PdopModule& p = pdop_[m];
  Sink sink(*this, m, unix_offset);
  const TimePoint at = steady_time_of(frame, now, unix_offset);
  if (frame.follows_loss()) p.reassembler->on_frames_lost(at, sink);
  // Frames of nodes without a surface id go on to the translator, which counts them. The nodes'
  // RPDOP acknowledgements are the segmenter's: the surface acknowledges its master itself.
  if (map_.surface_of(m, frame.id & canopen::pdop::kMaxNode) == 0) return false;
  if (!p.reassembler->on_frame(frame, at, sink) &&
      !p.segmenter->on_frame(frame, now, segmenter_out_)) {
    return false;
  }
  flush_segmenter(m);
  return true;
}

void GatewayPdopWork::on_node_event(const NodeEvent& e, TimePoint now) {
  if (!reassembles(e.module_index)) return;
  if (e.kind != NodeEvent::Kind::booted && e.kind != NodeEvent::Kind::renamed &&
      e.kind != NodeEvent::Kind::loader_booted) {
    return;
  }
  PdopModule& p = pdop_[e.module_index];
  Sink sink(*this, e.module_index, std::chrono::nanoseconds(0));  // discards carry no time
  for (NodeId node : {e.local, e.previous_local}) {
    if (node == 0 || node > canopen::pdop::kMaxNode) continue;
    p.reassembler->on_node_restart(node, now, sink);
    p.segmenter->cancel_node(node, now, segmenter_out_);
  }
  flush_segmenter(e.module_index);
}

void GatewayPdopWork::on_rpdop_packets(const v1::PdopPackets& packets, TimePoint now) {
  for (const v1::PdopPacket& p : packets.packets()) {
    ++counters_.rpdop_packets;
    std::optional<NodeOwner> owner;
    if (p.surface_node() >= 1 && p.surface_node() <= canopen::pdop::kMaxNode) {
      owner = map_.owner_of_surface(static_cast<NodeId>(p.surface_node()));
    }
    if (!owner || !reassembles(owner->module_index) ||
        (p.module_id() != kAnyModule && p.module_id() != modules_[owner->module_index].id)) {
      warn_.warn(Warn::kRpdopUnknown,
                 "gateway {}: RPDOP packet for surface node {} of module {}, which is no pdop "
                 "node of this gateway: refused (counted)",
                 log_name_, p.surface_node(), p.module_id());
      ++counters_.rpdop_failed;
      if (v1::RpdopOutcome* r = add_outcome_report()) {
        r->set_request_id(p.request_id());
        r->set_module_id(p.module_id());
        r->set_surface_node(p.surface_node());
        r->set_rpdo(p.pdo());
        r->set_result(v1::RpdopOutcome::REFUSED_ADDRESS);
      }
      continue;
    }
    const std::size_t m = owner->module_index;
    const std::string& data = p.data();
    pdop_[m].segmenter->submit(owner->local, p.pdo(),
                               std::vector<std::uint8_t>(data.begin(), data.end()), p.request_id(),
                               now, segmenter_out_);
    flush_segmenter(m);
  }
}

void GatewayPdopWork::tick(TimePoint now, std::chrono::nanoseconds unix_offset) {
  for (std::size_t m = 0; m < pdop_.size(); ++m) {
    if (!pdop_[m].reassembler) continue;
    Sink sink(*this, m, unix_offset);
    pdop_[m].reassembler->tick(now, sink);
    pdop_[m].segmenter->tick(now, segmenter_out_);
    flush_segmenter(m);
  }
}

std::optional<GatewayPdopWork::TimePoint> GatewayPdopWork::next_deadline() const {
  std::optional<TimePoint> deadline;
  const auto earlier = [&deadline](std::optional<TimePoint> t) {
    if (t && (!deadline || *t < *deadline)) deadline = t;
  };
  for (const PdopModule& p : pdop_) {
    if (!p.reassembler) continue;
    earlier(p.reassembler->next_deadline());
    earlier(p.segmenter->next_deadline());
  }
  return deadline;
}

void GatewayPdopWork::announce_nodes() {
  announce_ = active_;
}

const v1::Payload* GatewayPdopWork::next_payload() {
  if (announce_) {
    queue_nodes();
    announce_ = false;
  }
  return out_.empty() ? nullptr : &out_.front().payload;
}

void GatewayPdopWork::pop_payload() {
  if (out_.empty()) return;
  out_bytes_ -= std::min(out_bytes_, out_.front().bytes);
  out_.pop_front();
}

void GatewayPdopWork::refuse_payload(std::size_t serialized_bytes) {
  ++counters_.refused;
  warn_.warn(Warn::kRefused,
             "gateway {}: a PDO Packet payload of {} bytes exceeds the resend buffer: refused "
             "(counted as pdop-refused)",
             log_name_, serialized_bytes);
  pop_payload();
}

void GatewayPdopWork::produce(backbone::PayloadSink& sink, std::size_t max_reliable_bytes) {
  while (const v1::Payload* front = next_payload()) {
    // A packet larger than one write still goes: the session writes any message it takes.
    const std::size_t size = front->ByteSizeLong();
    if (size > max_reliable_bytes) {
      // Never accepted by the resend buffer (config validation prevents it): do not block.
      refuse_payload(size);
      continue;
    }
    if (sink.room() == 0 || !sink.reliable_room(size)) return;  // serialized only when it goes
    sink.send_reliable(front->SerializeAsString());
    pop_payload();
  }
}

std::uint64_t GatewayPdopWork::dropped_frames() const {
  std::uint64_t dropped = 0;
  for (const PdopModule& p : pdop_) {
    if (p.reassembler) dropped += p.reassembler->counters().dropped_frames;
  }
  return dropped;
}

v1::RpdopOutcome* GatewayPdopWork::add_outcome_report() {
  v1::Payload* payload = payload_for(v1::Payload::kPdopReports, 40);
  return payload ? payload->mutable_pdop_reports()->add_outcomes() : nullptr;
}

v1::Payload* GatewayPdopWork::payload_for(v1::Payload::BodyCase kind, std::size_t adding_bytes) {
  if (out_bytes_ + adding_bytes > max_queued_bytes_) {
    ++counters_.refused;
    warn_.warn(Warn::kRefused,
               "gateway {}: PDO Packet queue full ({} bytes): packets and reports refused "
               "(counted as pdop-refused; the link is too slow or down too long)",
               log_name_, out_bytes_);
    return nullptr;
  }
  out_bytes_ += adding_bytes;
  if (!out_.empty() && out_.back().payload.body_case() == kind &&
      out_.back().bytes + adding_bytes <= kBatchBytes) {
    out_.back().bytes += adding_bytes;
    return &out_.back().payload;
  }
  out_.push_back({v1::Payload(), adding_bytes});
  return &out_.back().payload;
}

void GatewayPdopWork::queue_nodes() {
  v1::Payload payload;
  v1::PdopNodes& nodes = *payload.mutable_pdop_nodes();
  for (std::size_t m = 0; m < pdop_.size() && m < map_.modules().size(); ++m) {
    if (map_.modules()[m].profile != IdProfile::pdop) continue;
    for (NodeId local = 1; local <= canopen::pdop::kMaxNode; ++local) {
      const NodeId surface = map_.surface_of(m, local);
      if (surface == 0) continue;
      v1::PdopNodes::Node& n = *nodes.add_nodes();
      n.set_module_id(modules_[m].id);
      n.set_local_node(local);
      n.set_surface_node(surface);
      n.set_whole(pdop_[m].reassembler != nullptr);
    }
  }
  out_.push_front({std::move(payload), 0});
}

void GatewayPdopWork::flush_segmenter(std::size_t m) {
  if (!segmenter_out_.frames.empty()) {
    bus_out_.push_back({m, std::move(segmenter_out_.frames)});
    segmenter_out_.frames.clear();
  }
  for (const PdopOutcome& o : segmenter_out_.outcomes) {
    if (o.result == PdopResult::complete) {
      ++counters_.rpdop_complete;
    } else {
      ++counters_.rpdop_failed;
      spdlog::info("gateway {}: module {} RPDOP {}", log_name_, modules_[m].id, to_string(o));
    }
    v1::RpdopOutcome* r = add_outcome_report();
    if (!r) continue;
    r->set_request_id(o.request_id);
    r->set_module_id(modules_[m].id);
    r->set_surface_node(map_.surface_of(m, o.node));
    r->set_rpdo(o.rpdo);
    r->set_result(to_proto(o.result));
    r->set_status(static_cast<std::uint32_t>(o.status));
    r->set_fragments(o.fragments);
    r->set_fragments_sent(o.fragments_sent);
    r->set_ack_requests(o.ack_requests);
    r->set_elapsed_us(static_cast<std::uint64_t>(
        std::chrono::duration_cast<std::chrono::microseconds>(o.elapsed).count()));
  }
  segmenter_out_.outcomes.clear();
}

}  // namespace canbridge::bridge
