// The surface role: one CAN interface where a master sees every module's nodes, fed by the
// gateways connected over the backbone (several at once, each serving its own modules).
#pragma once

#include <array>
#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/accepted_gateway.hpp"
#include "bridge/backbone_tuning.hpp"
#include "bridge/bus_writer.hpp"
#include "bridge/deadline_driver.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/gateway_table.hpp"
#include "bridge/loop_guard.hpp"
#include "bridge/role_statistics.hpp"
#include "bridge/sdo_link_guard.hpp"
#include "bridge/surface_counters.hpp"
#include "bridge/surface_gateway.hpp"
#include "bridge/surface_node_states.hpp"
#include "bridge/surface_pdop_work.hpp"
#include "bridge/surface_statistics.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"
#include "routing/rpdop_relay.hpp"

namespace canbridge::bridge {

// Which gateways the surface binds (docs/security.md): the configured ones only, each for its
// configured modules and surface node ids.
//
// Memory per peer is bounded by the configuration, not by who connects: one table entry and
// (once it has bound) one outbox per configured gateway, none per stranger. An outbox holds at
// most BackboneTuning::outbox's lane bounds in frames (reliable 65,536 + latest 4,096 + process
// 16,384 + fragments 16,384 by default), each a fixed-size entry (a can::Frame, its module and
// time: 40 bytes on x86-64, plus the queue's own per-entry overhead), so the frame bound is a
// byte bound: about 4 MB per configured gateway at the defaults, nothing for a peer that never
// binds.
struct SurfacePolicy {
  std::vector<AcceptedGateway> gateways;
  // A link that proved no identity (plain TCP, an unauthenticated serial line) binds nobody.
  // False only when the configured auth mode is plain.
  bool require_authenticated_peers = true;
  // The SDO time-out of the masters on the surface bus: a request in flight when its gateway's
  // link drops waits for its answer from the next link until four fifths of it have passed, and
  // no abort goes to a master for a request older than it (SdoLinkGuard::Options).
  std::chrono::milliseconds master_sdo_timeout{1000};
};

// A whole TPDOP packet as the surface received it, for backbone clients and tests.
struct SurfacePdopPacket {
  std::string gateway;
  std::uint32_t module_id = 0;
  canopen::NodeId local_node = 0;
  canopen::NodeId surface_node = 0;
  unsigned tpdo = 0;
  std::span<const std::uint8_t> data;  // valid during the call
  std::int64_t first_fragment_us = 0;  // Unix time, 0 when unknown
  std::uint32_t duration_us = 0;       // last fragment's time after the first's
  bool probable_repeat = false;        // see PdopPacket.probable_repeat
};

class Surface {
 public:
  Surface(boost::asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
          SurfacePolicy policy, BackboneTuning tuning = {}, bool conflate_pdos = true,
          RpdopRelayOptions rpdop_relay = {});
  ~Surface();

  void start();
  // Takes a new gateway link (accepted TCP connection or opened serial line). Its hello decides
  // which configured gateway it belongs to (GatewayTable::admit); a refused peer is told the
  // reason only when its link proved who it is, else just "refused" (details: the local log).
  void attach(std::shared_ptr<backbone::MessageLink> link);
  // Called when a hello on `link` was admitted and the link carries a gateway from now on (the
  // TCP server stops counting it as pending: TcpServer::admitted). One observer.
  void on_link_bound(std::function<void(backbone::MessageLink&)> observer) {
    on_link_bound_ = std::move(observer);
  }
  void stop();
  // Called once when the surface stops itself because one of its loops ended or threw (its bus
  // gone for good, a bug): the process shuts down in order and exits non-zero.
  void on_failure(std::function<void(const std::string& reason)> handler) {
    on_failure_ = std::move(handler);
  }
  // Why the surface stopped itself; empty while it has not.
  const std::string& failure() const { return failure_; }

  SurfaceCounters counters() const;
  std::size_t gateways_ready() const;
  can::Bus& bus() { return *bus_; }
  std::string stats_line() const;
  // The typed snapshot behind `canbridge stats` and /metrics (bridge/role_statistics.hpp).
  RoleStatistics statistics() const;
  // Everything the stats line and statistics() say, gathered once (bridge/surface_statistics.hpp).
  SurfaceStatsSnapshot stats_snapshot() const;
  // Every TPDOP packet, whole, as it arrives (also put on the bus as fragments). One observer.
  void on_pdop_packet(std::function<void(const SurfacePdopPacket&)> observer) {
    pdop_observer_ = std::move(observer);
  }
  const RpdopRelay& rpdop_relay() const { return pdop_.relay(); }

  // Remote access (bridge/surface_remote.hpp) rides on these.
  // Who owns which surface node and module, and which gateways are connected.
  const GatewayTable& gateway_table() const { return table_; }
  // The nodes the gateways reported (node events), kept while a gateway is down.
  const SurfaceNodeStates& node_states() const { return node_states_; }
  // Sends `payload` (a serialized v1::Payload) reliably to a bound gateway, after what is queued
  // for it (also while its link is down: it goes when the link returns). False: never bound.
  bool send_to_gateway(GatewayTable::GatewayId gateway, std::string payload);
  // Remote results and progress (Payload remote_result, remote_progress) from a bound gateway;
  // valid during the call. One observer.
  void on_remote_payload(
      std::function<void(GatewayTable::GatewayId, const v1::Payload&)> observer) {
    remote_observer_ = std::move(observer);
  }
  // Every frame the surface writes to its bus (`module_id`: the module it came from, 0 for frames
  // the surface makes itself; `to_bus` true) and every batch it reads from it (module 0, `to_bus`
  // false). One observer; called on the surface's executor; without one: one branch per batch.
  using MonitorObserver =
      std::function<void(std::span<const can::Frame> frames, std::uint32_t module_id, bool to_bus)>;
  void on_monitor_frames(MonitorObserver observer) { monitor_ = std::move(observer); }

 private:
  using Gateway = SurfaceGateway;
  // What each gateway's stream reports, to the surface's handlers below.
  SurfaceGateway::Events gateway_events();

  // Returns the bus's error when the bus ends (closed, or gone for good).
  boost::asio::awaitable<std::error_code> read_bus();
  // Every loop the surface spawns ends here: one that ends while the surface runs stops it.
  void on_task_end(const std::string& task, const std::string& why);
  backbone::BindResult bind(const v1::Hello& hello, backbone::SessionLink& link);
  // A bound gateway's frame for the surface bus that is not its to send: counted, warned once.
  void drop_not_its_own(Gateway& from, NotItsOwn why, std::uint32_t cob);
  void on_payload(Gateway& from, std::span<const std::uint8_t> payload);
  void on_frames(Gateway& from, const v1::FrameBatch& batch);
  void on_node_events(Gateway& from, const v1::NodeEvents& events);
  void on_gateway_down(Gateway& gateway);
  // Takes the SDO requests to `node` (every node, if 0) out of what is queued for `gateway` and
  // what it was sent unacknowledged: their master is told they failed, so they must never reach
  // a node later. The guard accounts for each.
  void withdraw_sdo_requests_to(Gateway& gateway, std::uint8_t node);
  void on_gateway_restart(Gateway& gateway);
  // A frame meant for `gateway` that will never be sent: counted, an open SDO request aborted.
  void on_frame_dropped(const can::Frame& frame, backbone::ReliableDrop why);
  void on_payload_dropped(const std::string& payload, backbone::ReliableDrop why);
  // Every frame for the surface bus goes here, in order (BusWriter).
  // Queues a surface frame for one gateway; an SDO request it cannot take is aborted.
  void forward_to(Gateway& gateway, const can::Frame& frame, LoopGuard::Clock::time_point now);
  void send_to_bus(const can::Frame& frame, std::uint32_t module_id = 0);
  // Input from every gateway waits while the bus is backed up (BusWriteQueue::backlogged).
  void on_bus_backlog(bool backlogged);
  void on_pdop_packets(Gateway& from, const v1::PdopPackets& packets);
  // The PDOP work's view of a gateway.
  SurfacePdopWork::From pdop_from(const Gateway& gateway) const;
  // Sends the relay's acknowledgements to the bus and its packets to their gateways.
  // Also re-arms the deadline driver: the relay's deadline may have moved earlier.
  void flush_relay();

  enum Warn : std::size_t {
    kUnknownModule,
    kNoGateway,
    kMalformed,
    kRefused,
    kBusRefused,
    kUnclaimed,
    kStranger,
    kWarnKinds
  };

  boost::asio::any_io_executor executor_;
  std::string name_;
  std::unique_ptr<can::Bus> bus_;
  BackboneTuning tuning_;
  bool conflate_pdos_;
  backbone::SessionLink::Identity identity_;
  std::map<std::string, std::unique_ptr<Gateway>> gateways_;  // by name, once bound
  // The same, by id (GatewayTable's, SdoLinkGuard's): one slot per configured gateway, null
  // until it first binds.
  std::vector<Gateway*> by_id_;
  GatewayTable table_;  // who may bind, who owns which surface ids
  SdoLinkGuard guard_;
  // Every gateway's nodes by their events: the node summary of statistics().
  SurfaceNodeStates node_states_;
  SurfacePdopWork pdop_;  // pdop nodes' owners, the RPDOP relay, TPDOP packets and reports
  // One timer for every core with deadlines (the RPDOP relay, the SDO guard).
  DeadlineDriver deadlines_;
  std::function<void(const SurfacePdopPacket&)> pdop_observer_;
  LoopGuard loop_guard_;
  // Frames (TPDOP packets whole) waiting for room on the bus: bursts from the backbone outrun it.
  BusWriter writer_;
  std::vector<can::Frame> forward_;  // the surface frames of one batch that go to gateways
  std::vector<std::shared_ptr<backbone::SessionLink>> links_;  // links not known closed
  backbone::DeframerCounters closed_links_framing_{};          // of links dropped from links_
  backbone::LinkCounters closed_links_{};  // bytes, messages, writes of links dropped from links_
  backbone::SessionLogMemory session_log_;
  SurfaceCounters counters_;
  v1::Payload inbound_;
  std::vector<can::Frame> decoded_;
  std::vector<can::Frame> to_bus_;           // the decoded frames of one batch that go to the bus
  std::vector<can::Frame> to_bus_accepted_;  // ... of those, the ones the writer took
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
  std::function<void(const std::string&)> on_failure_;
  std::function<void(backbone::MessageLink&)> on_link_bound_;
  std::function<void(GatewayTable::GatewayId, const v1::Payload&)> remote_observer_;
  MonitorObserver monitor_;
  std::string failure_;
};

}  // namespace canbridge::bridge
