// The surface role: one CAN interface where a master sees every module's nodes, fed by the
// gateways connected over the backbone (several at once, each serving its own modules).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/backbone_tuning.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/loop_guard.hpp"
#include "bridge/sdo_link_guard.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

struct SurfaceCounters {
  backbone::SessionCounters session;
  OutboxCounters outbox;                 // summed over the gateways
  std::uint64_t from_bus = 0;            // frames read on the surface bus
  std::uint64_t to_bus = 0;              // frames written to the surface bus
  std::uint64_t frames_received = 0;     // frames decoded from the backbone
  std::uint64_t dropped_no_gateway = 0;  // surface frames while no gateway was ever known
  std::uint64_t bus_refused = 0;         // surface bus transmit queue full
  std::uint64_t malformed_payloads = 0;  // payloads that are not a valid, consistent batch
  std::uint64_t unknown_module = 0;      // batches for a module the gateway did not announce
  backbone::DeframerCounters framing{};  // CRC-framed links (serial), all links so far
  std::uint64_t sdo_aborted = 0;         // SDO requests answered with 0x05040000: gateway link down
  std::uint64_t echoes_dropped = 0;      // frames the surface wrote, read back from its bus
  std::uint64_t node_events = 0;         // node table events the gateways reported
  // SDO requests never sent because the master got an abort when their link went down: queued
  // ones are in outbox.sdo_requests_withdrawn, these were sent and not yet acknowledged.
  std::uint64_t sdo_requests_withdrawn_unacked = 0;
  std::uint64_t sdo_late_responses_dropped = 0;  // answers to requests the master saw aborted
};

class Surface {
 public:
  Surface(boost::asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
          BackboneTuning tuning = {}, bool conflate_pdos = true);
  ~Surface();

  void start();
  // Takes a new gateway link (accepted TCP connection or opened serial line). Its hello decides
  // which gateway it belongs to; a gateway announcing a module another connected gateway serves
  // is refused, with the reason sent to it.
  void attach(std::shared_ptr<backbone::MessageLink> link);
  void stop();

  SurfaceCounters counters() const;
  std::size_t gateways_ready() const;
  can::Bus& bus() { return *bus_; }
  std::string stats_line() const;

 private:
  struct Gateway;

  boost::asio::awaitable<void> read_bus();
  backbone::BindResult bind(const v1::Hello& hello);
  void on_payload(Gateway& from, std::span<const std::uint8_t> payload);
  void on_frames(Gateway& from, const v1::FrameBatch& batch);
  void on_node_events(Gateway& from, const v1::NodeEvents& events);
  void on_gateway_down(Gateway& gateway);
  void send_to_bus(const can::Frame& frame);

  enum Warn : std::size_t {
    kUnknownModule,
    kNoGateway,
    kMalformed,
    kRefused,
    kBusRefused,
    kWarnKinds
  };

  boost::asio::any_io_executor executor_;
  std::string name_;
  std::unique_ptr<can::Bus> bus_;
  BackboneTuning tuning_;
  bool conflate_pdos_;
  backbone::SessionLink::Identity identity_;
  std::map<std::string, std::unique_ptr<Gateway>> gateways_;  // by name, once seen
  std::vector<Gateway*> by_id_;                               // the same, by SdoLinkGuard id
  SdoLinkGuard guard_;
  LoopGuard loop_guard_;
  std::vector<can::Frame> forward_;  // the surface frames of one batch that go to gateways
  std::vector<std::shared_ptr<backbone::SessionLink>> links_;  // links not known closed
  backbone::DeframerCounters closed_links_framing_{};          // of links dropped from links_
  SurfaceCounters counters_;
  v1::Payload inbound_;
  std::vector<can::Frame> decoded_;
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
