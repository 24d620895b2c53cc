#include "bridge/backbone_session.hpp"

#include <spdlog/spdlog.h>

#include "backbone/delimited_codec.hpp"
#include "bridge/warn_once.hpp"

namespace canbridge::bridge {

namespace {
enum WarnKind : std::size_t {
  kMalformedEnvelope,
  kMalformedBatch,
  kUnknownModule,
  kBacklog,
  kKinds
};
WarnOnce<kKinds> g_warn;  // process-wide: one line per kind, counters carry the rest

const char* role_name(v1::Hello::Role role) {
  switch (role) {
    case v1::Hello::ROLE_GATEWAY:
      return "gateway";
    case v1::Hello::ROLE_SURFACE:
      return "surface";
    default:
      return "unspecified";
  }
}
}  // namespace

BackboneSession::BackboneSession(std::shared_ptr<backbone::MessageLink> link, v1::Hello own_hello,
                                 v1::Hello::Role expected_peer,
                                 std::vector<std::uint32_t> outbound_modules,
                                 std::size_t max_backlog_frames, SessionCounters& counters)
    : link_(std::move(link)),
      own_hello_(std::move(own_hello)),
      expected_peer_(expected_peer),
      outbound_(outbound_modules.size()),
      module_ids_(std::move(outbound_modules)),
      max_backlog_(max_backlog_frames),
      counters_(counters) {
  for (std::size_t i = 0; i < outbound_.size(); ++i) {
    builder_.start(*outbound_[i].envelope.mutable_frames(), module_ids_[i]);
  }
}

void BackboneSession::start(Handlers handlers) {
  handlers_ = std::move(handlers);
  std::weak_ptr<BackboneSession> weak = weak_from_this();
  link_->start(
      [weak](std::span<const std::uint8_t> bytes) {
        if (auto self = weak.lock()) self->on_message(bytes);
      },
      [weak](std::string& out) {
        if (auto self = weak.lock()) self->fill(out);
      },
      [weak](std::error_code ec) {
        auto self = weak.lock();
        if (!self || self->closed_) return;
        self->closed_ = true;
        spdlog::info("backbone: link to {} closed ({})",
                     self->ready_ ? self->peer_hello_.name() : std::string("peer"), ec.message());
        if (self->handlers_.on_closed) self->handlers_.on_closed();
      });
  link_->wake_writer();  // the hello goes first
}

void BackboneSession::close() {
  link_->close();
}

bool BackboneSession::queue(std::size_t slot, const can::Frame& frame) {
  if (backlog_ >= max_backlog_) {
    ++counters_.dropped_backlog;
    g_warn.warn(kBacklog, "backbone: outbound backlog full ({} frames): dropping frames (counted)",
                max_backlog_);
    return false;
  }
  Outbound& o = outbound_[slot];
  builder_.append(*o.envelope.mutable_frames(), frame);
  ++o.frames;
  ++backlog_;
  return true;
}

void BackboneSession::flush() {
  if (backlog_ != 0) link_->wake_writer();
}

// Called by the link's writer whenever the socket is free: everything queued since the last
// write leaves now, as one write (one message per module with frames).
void BackboneSession::fill(std::string& out) {
  if (!hello_sent_) {
    v1::Envelope hello;
    *hello.mutable_hello() = own_hello_;
    backbone::append_message(out, hello);
    hello_sent_ = true;
  }
  if (!ready_) return;  // frames wait for the peer's hello
  for (std::size_t i = 0; i < outbound_.size(); ++i) {
    Outbound& o = outbound_[i];
    if (o.frames == 0) continue;
    backbone::append_message(out, o.envelope);
    counters_.frames_sent += o.frames;
    ++counters_.batches_sent;
    builder_.start(*o.envelope.mutable_frames(), module_ids_[i]);
    o.frames = 0;
  }
  backlog_ = 0;
}

void BackboneSession::fail(const std::string& why) {
  ++counters_.protocol_errors;
  spdlog::error("backbone: {}; closing the link", why);
  link_->close();
}

void BackboneSession::on_message(std::span<const std::uint8_t> bytes) {
  if (closed_) return;
  if (!inbound_.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
    ++counters_.malformed_envelopes;
    g_warn.warn(kMalformedEnvelope, "backbone: a message is not a valid Envelope (counted)");
    return;
  }
  if (inbound_.has_hello()) {
    const v1::Hello& h = inbound_.hello();
    if (ready_) return fail("second hello from " + h.name());
    if (h.protocol_major() != kProtocolMajor) {
      return fail("peer '" + h.name() + "' speaks protocol " + std::to_string(h.protocol_major()) +
                  "." + std::to_string(h.protocol_minor()) + ", this side speaks " +
                  std::to_string(kProtocolMajor) + "." + std::to_string(kProtocolMinor));
    }
    if (h.role() != expected_peer_) {
      return fail(std::string("peer '") + h.name() + "' is a " + role_name(h.role()) +
                  ", expected a " + role_name(expected_peer_));
    }
    peer_hello_ = h;
    ready_ = true;
    spdlog::info("backbone: {} '{}' ready (protocol {}.{}, {} module(s))", role_name(h.role()),
                 h.name(), h.protocol_major(), h.protocol_minor(), h.module_ids_size());
    if (handlers_.on_ready) handlers_.on_ready(peer_hello_);
    link_->wake_writer();
    return;
  }
  if (!ready_) return fail("peer sent data before its hello");
  if (inbound_.has_frames()) {
    decoded_.clear();
    const BatchError err = decode_frame_batch(inbound_.frames(), decoded_);
    if (err != BatchError::none) {
      ++counters_.malformed_batches;
      g_warn.warn(kMalformedBatch, "backbone: malformed frame batch ({}): dropped (counted)",
                  to_string(err));
      return;
    }
    counters_.frames_received += decoded_.size();
    handlers_.on_frames(inbound_.frames().module_id(), decoded_);
  }
}

}  // namespace canbridge::bridge
