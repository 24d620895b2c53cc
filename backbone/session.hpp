// The backbone session layer over any MessageLink: hello exchange with version/role checks,
// keepalive and dead-link detection, and reliable streams (sequence numbers, cumulative acks,
// retransmission) that survive link cuts, so each reliable payload arrives exactly once, in order.
#pragma once

#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "backbone/message_link.hpp"
#include "backbone/peer_stream.hpp"
#include "backbone/session_core.hpp"

namespace canbridge::backbone {

// One link's session: a SessionCore driven by a MessageLink and one timer. Everything it
// decides is the core's; this class only forwards messages, writes, ticks and closes.
class SessionLink : public std::enable_shared_from_this<SessionLink>, private SessionShell {
 public:
  using Identity = SessionIdentity;
  // Called once with the peer's hello after version and role were accepted.
  using Binder = std::function<BindResult(const v1::Hello& peer, SessionLink& link)>;

  // `preset` is the stream of a side with exactly one peer (the gateway), whose hello can go out
  // before the peer's arrives; null when the binder picks the stream (the surface). `log` is the
  // side's (null: this link's own).
  static std::shared_ptr<SessionLink> create(std::shared_ptr<MessageLink> link,
                                             const Identity& identity,
                                             const SessionOptions& options, PeerStream* preset,
                                             Binder binder, SessionCounters& counters,
                                             SessionLogMemory* log = nullptr);
  ~SessionLink();

  void start();
  void close();
  bool ready() const { return core_.ready(); }
  PeerStream* stream() const { return core_.stream(); }
  const std::shared_ptr<MessageLink>& message_link() const { return link_; }
  // Who the peer proved to be: the transport's proof (TLS), else the session's own (the serial
  // challenge-response); empty when nothing was proven (plain operation).
  const std::string& authenticated_peer() const {
    const std::string& transport = link_->authenticated_peer();
    return transport.empty() ? core_.authenticated_peer() : transport;
  }

 private:
  SessionLink(std::shared_ptr<MessageLink> link, const Identity& identity,
              const SessionOptions& options, PeerStream* preset, Binder binder,
              SessionCounters& counters, SessionLogMemory* log);

  std::chrono::steady_clock::time_point now() const;
  // The time of the input batch being delivered: the clock is read once per batch (a syscall
  // where there is no vDSO), not once per message.
  std::chrono::steady_clock::time_point input_now();
  void on_closed();
  void arm_timer();
  void on_timer();
  // SessionShell
  void wake_writer() override;
  void close_link(std::error_code reason) override;
  void pause_reading(bool paused) override;
  BindResult bind(const v1::Hello& peer) override;
  void carry(PeerStream& stream) override;
  bool input_waiting() override { return link_->input_waiting(); }

  std::shared_ptr<MessageLink> link_;
  std::function<std::chrono::steady_clock::time_point()> clock_;
  Binder binder_;
  SessionLogMemory own_log_;
  SessionCore core_;
  std::uint64_t rx_bytes_at_tick_ = 0;  // the link's rx_bytes at the last tick
  std::uint64_t input_batch_ = 0;       // the link's input batch input_time_ was read for
  std::chrono::steady_clock::time_point input_time_{};
  boost::asio::steady_timer timer_;  // at the core's next deadline
};

// A random 64-bit id (never 0) for SessionLink::Identity::session_id.
std::uint64_t random_session_id();

}  // namespace canbridge::backbone
