// One backbone connection as the bridge sees it: hello exchange, then batches of CAN frames per
// module in both directions, packed into as few writes as the link allows.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "backbone/message_link.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"

namespace canbridge::bridge {

inline constexpr std::uint32_t kProtocolMajor = 1;
inline constexpr std::uint32_t kProtocolMinor = 0;

// Counters of one role, summed over all its sessions (sessions come and go with the link).
struct SessionCounters {
  std::uint64_t frames_sent = 0;      // frames handed to the backbone
  std::uint64_t frames_received = 0;  // frames decoded from the backbone
  std::uint64_t batches_sent = 0;
  std::uint64_t dropped_backlog = 0;      // frames refused because the outbound backlog was full
  std::uint64_t malformed_envelopes = 0;  // messages that are not a valid Envelope
  std::uint64_t malformed_batches = 0;    // FrameBatch columns inconsistent
  std::uint64_t protocol_errors = 0;      // hello missing, wrong role, incompatible version
  std::uint64_t unknown_module = 0;       // batches naming a module this side does not know
};

class BackboneSession : public std::enable_shared_from_this<BackboneSession> {
 public:
  struct Handlers {
    std::function<void(const v1::Hello&)> on_ready;  // peer's hello accepted
    // Frames of one received batch, in order.
    std::function<void(std::uint32_t module_id, std::span<const can::Frame>)> on_frames;
    std::function<void()> on_closed;  // once, whatever the reason
  };

  // `outbound_modules` are the module ids this side sends frames for; queue() takes an index
  // into it. `expected_peer` is the role the other end must announce.
  BackboneSession(std::shared_ptr<backbone::MessageLink> link, v1::Hello own_hello,
                  v1::Hello::Role expected_peer, std::vector<std::uint32_t> outbound_modules,
                  std::size_t max_backlog_frames, SessionCounters& counters);

  // Starts the link; handlers are called from the link's loops on the session's executor.
  void start(Handlers handlers);
  void close();
  bool ready() const { return ready_; }
  bool is_closed() const { return closed_; }
  const v1::Hello& peer_hello() const { return peer_hello_; }

  // Adds a frame to the outbound batch of outbound_modules[slot]. False (counted) when the
  // backlog is full. Call flush() after a run of queue() calls.
  bool queue(std::size_t slot, const can::Frame& frame);
  void flush();

 private:
  void on_message(std::span<const std::uint8_t> bytes);
  void fill(std::string& out);
  void fail(const std::string& why);

  struct Outbound {
    v1::Envelope envelope;  // body = frames, built in place
    std::size_t frames = 0;
  };

  std::shared_ptr<backbone::MessageLink> link_;
  v1::Hello own_hello_;
  v1::Hello peer_hello_;
  v1::Hello::Role expected_peer_;
  std::vector<Outbound> outbound_;
  std::vector<std::uint32_t> module_ids_;
  std::size_t backlog_ = 0;
  std::size_t max_backlog_;
  bool hello_sent_ = false;
  bool ready_ = false;
  bool closed_ = false;
  FrameBatchBuilder builder_;
  v1::Envelope inbound_;
  std::vector<can::Frame> decoded_;
  SessionCounters& counters_;
  Handlers handlers_;
};

}  // namespace canbridge::bridge
