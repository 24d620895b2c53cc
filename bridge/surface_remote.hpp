// The surface's remote access (bridge/remote_access.hpp): routes an operator's request to the
// gateway that owns the node, carries it over the backbone as one RemoteRequest, and completes
// it with that gateway's RemoteResult, also one resent late after a stall or a cut; when none can
// come, with timed_out or, for a request that may have changed the node, outcome_unknown
// (bridge/remote_request_ledger.hpp decides which).
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "bridge/accepted_gateway.hpp"
#include "bridge/remote_access.hpp"
#include "bridge/remote_request_ledger.hpp"
#include "bridge/surface.hpp"
#include "bridge/surface_remote_options.hpp"

namespace canbridge::bridge {

struct SurfaceRemoteCounters {
  std::uint64_t requests = 0;         // sent to a gateway
  std::uint64_t refused_at_once = 0;  // unknown net/node, gateway not connected, bad argument
  std::uint64_t results = 0;          // answered by a gateway
  std::uint64_t overdue = 0;          // past the answer deadline: cancel sent, still waiting
  std::uint64_t late_answers = 0;     // ... and then answered by the gateway (its result)
  std::uint64_t timed_out = 0;        // completed with timed_out: never ran, or changes nothing
  std::uint64_t outcome_unknown = 0;  // completed with outcome_unknown: it may have run
  std::uint64_t cancelled = 0;        // cancel() of an open request
  // Results and progress for ids this surface process has no open request for: an answer to a
  // request that timed out or was cancelled, or to a surface process before this one.
  std::uint64_t unknown_results = 0;
  std::uint64_t monitor_frames = 0;  // frames handed to monitor subscribers (once per frame)
};

class SurfaceRemote final : public RemoteAccess {
 public:
  using Clock = std::chrono::steady_clock;

  // `gateways`: the surface's configured gateways (SurfacePolicy::gateways), so that a node or
  // network of a gateway that is down (or never connected) is "not connected", not "unknown".
  // `first_id`: the first request id; default the process's start in Unix µs, so that a
  // restarted surface never reuses an id a gateway may still answer.
  SurfaceRemote(boost::asio::any_io_executor executor, Surface& surface,
                std::vector<AcceptedGateway> gateways, SurfaceRemoteOptions options = {},
                std::optional<RequestId> first_id = std::nullopt);
  ~SurfaceRemote() override;
  SurfaceRemote(const SurfaceRemote&) = delete;
  SurfaceRemote& operator=(const SurfaceRemote&) = delete;

  // Every open request completes with operation_canceled; the surface's hooks are released.
  void stop();

  std::vector<NetworkInfo> networks() const override;
  RequestId sdo(RemoteSdo request, Done done) override;
  RequestId nmt(RemoteTarget target, NmtCommand command, Done done) override;
  RequestId set_node_id(RemoteTarget target, canopen::NodeId new_node, Done done) override;
  RequestId flash(RemoteTarget target, std::vector<std::uint8_t> image,
                  std::function<void(const FlashProgress&)> progress, Done done) override;
  RequestId lss(NetworkNumber net, std::string command, std::vector<std::uint32_t> args,
                Done done) override;
  void cancel(RequestId id) override;
  void nodes(NetworkNumber net,
             std::function<void(std::vector<NodeRow>, std::error_code)> done) override;
  std::uint64_t subscribe(std::function<void(const MonitorFrame&)> observer) override;
  void unsubscribe(std::uint64_t id) override;

  // The 309-3 network number of a module (SurfaceRemoteOptions::networks, else id + 1).
  NetworkNumber network_of(std::uint32_t module_id) const;
  const SurfaceRemoteCounters& counters() const { return counters_; }
  std::size_t open_requests() const { return pending_.size(); }

 private:
  using GatewayId = GatewayTable::GatewayId;
  using TimePoint = Clock::time_point;

  // Where a request goes: the gateway, its module, the node on the module (or by surface id).
  struct Route {
    GatewayId gateway = 0;
    std::uint32_t module_id = 0;
    canopen::NodeId local_node = 0;
    canopen::NodeId surface_node = 0;  // net 0: the gateway resolves the local id
  };
  struct Resolved {
    std::optional<Route> route;
    std::error_code error;
    std::string detail;
  };
  // Several requests answered as one (nodes(), NMT to every node of net 0).
  struct Group;
  // A request handed to a gateway; its deadlines are the ledger's.
  struct Pending {
    GatewayId gateway = 0;
    Done done;
    std::function<void(const FlashProgress&)> progress;
    std::shared_ptr<Group> group;
  };
  using Effect = RemoteRequestLedger::Effect;

  Resolved resolve(RemoteTarget target, bool node_zero_allowed) const;
  // The configured gateway serving `module_id`; nullopt: none.
  std::optional<GatewayId> configured_owner_of_module(std::uint32_t module_id) const;
  std::optional<GatewayId> configured_owner_of_node(canopen::NodeId surface_node) const;
  std::optional<std::uint32_t> module_of_network(NetworkNumber net) const;
  bool connected(GatewayId gateway) const;
  // The rows of a gateway that is down (`module_id` 0: all its modules), from the surface's own
  // view of its nodes (SurfaceNodeStates), each lost.
  void add_rows_of_down_gateway(GatewayId gateway, std::uint32_t module_id,
                                std::vector<NodeRow>& rows) const;
  std::string gateway_name(GatewayId gateway) const;

  // Sends the request (its route and `op` already in `request`) and keeps it open until its
  // result, `within` from now or, overdue, the ledger's resend window after that (a progress
  // report restarts the wait: a long transfer that moves never times out, a stalled one does).
  RequestId send(GatewayId gateway, v1::RemoteRequest request, Effect effect,
                 std::chrono::milliseconds within, Done done,
                 std::function<void(const FlashProgress&)> progress = nullptr,
                 std::shared_ptr<Group> group = nullptr);
  // Completes `done` later, on the executor, never inside the caller's call.
  void post(Done done, RemoteOutcome outcome);
  RequestId refuse(Done done, std::error_code error, std::string detail);
  RequestId route_and_send(RemoteTarget target, bool node_zero_allowed, v1::RemoteRequest request,
                           Effect effect, std::chrono::milliseconds within, Done done,
                           std::function<void(const FlashProgress&)> progress = nullptr);

  void on_remote_payload(GatewayId from, const v1::Payload& payload);
  void on_result(GatewayId from, const v1::RemoteResult& result);
  // A request the ledger ended without the gateway's result.
  void end_unanswered(const RemoteRequestLedger::Ended& ended);
  void finish(RequestId id, RemoteOutcome outcome);
  // The gateway's session now (0: not connected); a new one ends what the old one was asked.
  RemoteRequestLedger::SessionId session_of(GatewayId gateway) const;
  void check_gateway_sessions();
  void on_deadlines();
  void arm_timer();
  void on_monitor(std::span<const can::Frame> frames, std::uint32_t module_id, bool to_bus);

  boost::asio::any_io_executor executor_;
  Surface& surface_;
  std::vector<AcceptedGateway> gateways_;
  SurfaceRemoteOptions options_;
  RequestId next_id_;
  std::unordered_map<RequestId, Pending> pending_;
  RemoteRequestLedger ledger_;
  boost::asio::steady_timer timer_;
  TimePoint armed_until_ = TimePoint::max();
  // Handlers that outlive this object (the timer's) see it expired and do nothing.
  std::shared_ptr<int> alive_ = std::make_shared<int>(0);
  std::map<std::uint64_t, std::function<void(const MonitorFrame&)>> subscribers_;
  std::uint64_t next_subscriber_ = 1;
  bool dispatching_ = false;  // on_monitor() is calling the subscribers
  bool stopped_ = false;
  SurfaceRemoteCounters counters_;
};

}  // namespace canbridge::bridge
