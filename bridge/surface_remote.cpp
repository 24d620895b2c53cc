#include "bridge/surface_remote.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <boost/asio/post.hpp>
#include <tuple>

#include "canopen/sdo_abort.hpp"

namespace canbridge::bridge {

namespace asio = boost::asio;

namespace {

std::error_code errc(std::errc e) {
  return std::make_error_code(e);
}

std::int64_t unix_us_now() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// How long set-node-id may take at the gateway beyond the backbone: its wait for the boot-up on
// the new id (GatewayRemoteOptions::boot_timeout's default).
constexpr std::chrono::milliseconds kBootWait{10000};
// LSS: a few request/response exchanges of CiA 305 (each at most about a second).
constexpr std::chrono::milliseconds kLssWait{2000};

void sort_rows(std::vector<NodeRow>& rows) {
  std::sort(rows.begin(), rows.end(), [](const NodeRow& a, const NodeRow& b) {
    return std::tie(a.net, a.local_node) < std::tie(b.net, b.local_node);
  });
}

NodeRow row_of(const v1::NodeRow& r, NetworkNumber net, const std::string& gateway) {
  NodeRow row;
  row.net = net;
  row.module_id = r.module_id();
  row.gateway = gateway;
  row.local_node = static_cast<canopen::NodeId>(r.local_node());
  row.surface_node = static_cast<canopen::NodeId>(r.surface_node());
  row.profile = r.profile();
  row.kind = r.kind();
  row.nmt_state = static_cast<std::uint8_t>(r.nmt_state());
  row.in_loader = r.in_loader();
  row.lost = r.lost();
  if (r.heartbeat_age_ms() >= 0)
    row.heartbeat_age = std::chrono::milliseconds(r.heartbeat_age_ms());
  if (r.last_emcy_age_ms() >= 0 || r.last_emcy_code() != 0) {
    row.last_emcy_code = static_cast<std::uint16_t>(r.last_emcy_code());
    row.last_emcy_register = static_cast<std::uint8_t>(r.last_emcy_register());
  }
  row.boot_count = r.boot_count();
  return row;
}

}  // namespace

// Requests answered as one: the node tables of several gateways, an NMT command to every node
// of the default network (one request per module).
struct SurfaceRemote::Group {
  std::size_t open = 0;
  std::size_t failed = 0;
  std::error_code first_error;
  std::string first_detail;
  std::vector<NodeRow> rows;
  std::function<void(std::vector<NodeRow>, std::error_code)> nodes_done;  // nodes()
  Done done;                                                              // NMT to all
};

SurfaceRemote::SurfaceRemote(asio::any_io_executor executor, Surface& surface,
                             std::vector<AcceptedGateway> gateways, SurfaceRemoteOptions options,
                             std::optional<RequestId> first_id)
    : executor_(std::move(executor)),
      surface_(surface),
      gateways_(std::move(gateways)),
      options_(std::move(options)),
      next_id_(first_id ? *first_id : static_cast<RequestId>(unix_us_now())),
      ledger_(RemoteRequestLedger::Options{.resend_window = options_.resend_window}),
      timer_(executor_) {
  surface_.on_remote_payload(
      [this](GatewayId from, const v1::Payload& payload) { on_remote_payload(from, payload); });
}

SurfaceRemote::~SurfaceRemote() {
  stop();
}

void SurfaceRemote::stop() {
  if (stopped_) return;
  stopped_ = true;
  surface_.on_remote_payload(nullptr);
  surface_.on_monitor_frames(nullptr);
  subscribers_.clear();
  timer_.cancel();
  std::vector<RequestId> open;
  for (const auto& [id, p] : pending_) open.push_back(id);
  for (RequestId id : open) {
    finish(id, {errc(std::errc::operation_canceled), {}, "the surface is stopping"});
  }
}

NetworkNumber SurfaceRemote::network_of(std::uint32_t module_id) const {
  for (const auto& [module, net] : options_.networks) {
    if (module == module_id) return net;
  }
  return module_id + 1;
}

std::optional<std::uint32_t> SurfaceRemote::module_of_network(NetworkNumber net) const {
  for (const AcceptedGateway& g : gateways_) {
    for (std::uint32_t m : g.modules) {
      if (network_of(m) == net) return m;
    }
  }
  return std::nullopt;
}

std::optional<GatewayTable::GatewayId> SurfaceRemote::configured_owner_of_module(
    std::uint32_t module_id) const {
  // The table's ids are the configuration's positions (GatewayTable).
  for (std::size_t i = 0; i < gateways_.size(); ++i) {
    const auto& modules = gateways_[i].modules;
    if (std::find(modules.begin(), modules.end(), module_id) != modules.end()) {
      return static_cast<GatewayId>(i);
    }
  }
  return std::nullopt;
}

std::optional<GatewayTable::GatewayId> SurfaceRemote::configured_owner_of_node(
    canopen::NodeId surface_node) const {
  for (std::size_t i = 0; i < gateways_.size(); ++i) {
    const AcceptedGateway& g = gateways_[i];
    bool serves = std::find(g.surface_nodes.begin(), g.surface_nodes.end(), surface_node) !=
                  g.surface_nodes.end();
    if (g.surface_nodes.empty()) {
      for (ModuleId m : g.modules) {
        for (const auto& [local, surface] : NodeMap::default_pairs(m)) {
          serves = serves || surface == surface_node;
        }
      }
    }
    if (serves) return static_cast<GatewayId>(i);
  }
  return std::nullopt;
}

bool SurfaceRemote::connected(GatewayId gateway) const {
  const auto& entries = surface_.gateway_table().gateways();
  return gateway < entries.size() && entries[gateway].connected;
}

std::string SurfaceRemote::gateway_name(GatewayId gateway) const {
  return gateway < gateways_.size() ? gateways_[gateway].name : std::string("?");
}

std::vector<NetworkInfo> SurfaceRemote::networks() const {
  std::vector<NetworkInfo> nets;
  nets.push_back({0, 0, "", false, surface_.gateways_ready() > 0});
  for (std::size_t i = 0; i < gateways_.size(); ++i) {
    for (std::uint32_t m : gateways_[i].modules) {
      // Whether the gateway routes LSS to this module only it knows (its lss_module): the
      // surface lets the request through and the gateway refuses it.
      nets.push_back(
          {network_of(m), m, gateways_[i].name, true, connected(static_cast<GatewayId>(i))});
    }
  }
  std::sort(nets.begin(), nets.end(),
            [](const NetworkInfo& a, const NetworkInfo& b) { return a.net < b.net; });
  return nets;
}

SurfaceRemote::Resolved SurfaceRemote::resolve(RemoteTarget target, bool node_zero_allowed) const {
  if (target.node > canopen::kMaxNodeId || (target.node == 0 && !node_zero_allowed)) {
    return {std::nullopt, errc(std::errc::no_such_device_or_address),
            "node " + std::to_string(target.node) + ": not a node id (1..127)"};
  }
  if (target.net != 0) {
    const std::optional<std::uint32_t> module = module_of_network(target.net);
    if (!module) {
      return {std::nullopt, errc(std::errc::no_such_device_or_address),
              "no network " + std::to_string(target.net)};
    }
    const GatewayId gateway = *configured_owner_of_module(*module);
    if (!connected(gateway)) {
      return {std::nullopt, errc(std::errc::host_unreachable),
              "gateway '" + gateway_name(gateway) + "' of network " + std::to_string(target.net) +
                  " is not connected"};
    }
    return {Route{gateway, *module, target.node, 0}, {}, {}};
  }
  // The default network: surface node ids, owned by whichever gateway's claims hold them now.
  const GatewayTable& table = surface_.gateway_table();
  if (const std::optional<GatewayId> owner = table.owner_of_node(target.node)) {
    const GatewayTable::Entry& entry = table.gateways()[*owner];
    if (!entry.connected) {
      return {std::nullopt, errc(std::errc::host_unreachable),
              "gateway '" + entry.name + "' of node " + std::to_string(target.node) +
                  " is not connected"};
    }
    std::optional<std::uint32_t> module;
    if (entry.claims) {
      for (const ModuleClaim& m : entry.claims->modules) {
        if (std::binary_search(m.surface_nodes.begin(), m.surface_nodes.end(), target.node)) {
          module = m.id;
        }
      }
    } else if (entry.modules.size() == 1) {
      module = entry.modules.front();
    }
    if (module) return {Route{*owner, *module, 0, target.node}, {}, {}};
  } else if (const std::optional<GatewayId> configured = configured_owner_of_node(target.node);
             configured && !connected(*configured)) {
    return {std::nullopt, errc(std::errc::host_unreachable),
            "gateway '" + gateway_name(*configured) + "' of node " + std::to_string(target.node) +
                " is not connected"};
  }
  return {std::nullopt, errc(std::errc::no_such_device_or_address),
          "no node " + std::to_string(target.node) + " on network 0"};
}

void SurfaceRemote::post(Done done, RemoteOutcome outcome) {
  if (!done) return;
  asio::post(executor_, [done = std::move(done), outcome = std::move(outcome)]() mutable {
    done(std::move(outcome));
  });
}

RemoteAccess::RequestId SurfaceRemote::refuse(Done done, std::error_code error,
                                              std::string detail) {
  ++counters_.refused_at_once;
  const RequestId id = next_id_++;
  post(std::move(done), {error, {}, std::move(detail)});
  return id;
}

RemoteAccess::RequestId SurfaceRemote::send(GatewayId gateway, v1::RemoteRequest request,
                                            Effect effect, std::chrono::milliseconds within,
                                            Done done,
                                            std::function<void(const FlashProgress&)> progress,
                                            std::shared_ptr<Group> group) {
  const RequestId id = next_id_++;
  request.set_request_id(id);
  v1::Payload payload;
  *payload.mutable_remote_request() = std::move(request);
  check_gateway_sessions();  // what a restarted gateway was asked ends before it is asked more
  // A gateway that is down would get the request when it returns, long after the operator
  // was told: refused now instead.
  const bool handed_over = !stopped_ && connected(gateway) &&
                           surface_.send_to_gateway(gateway, payload.SerializeAsString());
  if (ledger_.open(id, gateway, handed_over ? session_of(gateway) : 0, effect, Clock::now(),
                   within)) {
    ++counters_.refused_at_once;
    if (group) {
      // Counted as one failed member of the group.
      pending_[id] = Pending{gateway, nullptr, nullptr, std::move(group)};
      finish(id, {errc(std::errc::host_unreachable), {}, "gateway not connected"});
    } else {
      post(std::move(done), {errc(std::errc::host_unreachable),
                             {},
                             "gateway '" + gateway_name(gateway) + "' is not connected"});
    }
    return id;
  }
  ++counters_.requests;
  pending_[id] = Pending{gateway, std::move(done), std::move(progress), std::move(group)};
  arm_timer();
  return id;
}

RemoteAccess::RequestId SurfaceRemote::route_and_send(
    RemoteTarget target, bool node_zero_allowed, v1::RemoteRequest request, Effect effect,
    std::chrono::milliseconds within, Done done,
    std::function<void(const FlashProgress&)> progress) {
  Resolved r = resolve(target, node_zero_allowed);
  if (!r.route) return refuse(std::move(done), r.error, std::move(r.detail));
  request.set_module_id(r.route->module_id);
  request.set_local_node(r.route->local_node);
  request.set_surface_node(r.route->surface_node);
  return send(r.route->gateway, std::move(request), effect, within, std::move(done),
              std::move(progress));
}

RemoteAccess::RequestId SurfaceRemote::sdo(RemoteSdo sdo, Done done) {
  v1::RemoteRequest request;
  request.set_timeout_ms(static_cast<std::uint32_t>(sdo.timeout.count()));
  v1::SdoOp& op = *request.mutable_sdo();
  op.set_upload(sdo.upload);
  op.set_index(sdo.index);
  op.set_subindex(sdo.sub);
  op.set_data(sdo.data.data(), sdo.data.size());
  op.set_block_size(sdo.block_size);
  // A download's data crosses the backbone before the gateway starts: a second per KiB lets it
  // cross a 9600 bit/s serial line. Once the transfer runs, the gateway's progress reports keep
  // restarting the wait.
  const auto crossing = std::chrono::milliseconds(sdo.data.size());
  return route_and_send(sdo.target, false, std::move(request),
                        sdo.upload ? Effect::none : Effect::changes_node,
                        sdo.timeout + options_.answer_slack + crossing, std::move(done));
}

RemoteAccess::RequestId SurfaceRemote::nmt(RemoteTarget target, NmtCommand command, Done done) {
  v1::RemoteRequest request;
  request.mutable_nmt()->set_command(static_cast<std::uint32_t>(command));
  if (target.net != 0 || target.node != 0) {
    return route_and_send(target, true, std::move(request), Effect::changes_node,
                          options_.answer_slack, std::move(done));
  }
  // Every node of the default network: every module of every configured gateway, each told
  // once; one failure (a gateway down) fails the whole, after the others were told.
  auto group = std::make_shared<Group>();
  group->done = std::move(done);
  std::vector<std::pair<GatewayId, std::uint32_t>> modules;
  for (std::size_t i = 0; i < gateways_.size(); ++i) {
    for (std::uint32_t m : gateways_[i].modules) modules.emplace_back(static_cast<GatewayId>(i), m);
  }
  if (modules.empty()) {
    return refuse(std::move(group->done), errc(std::errc::no_such_device_or_address), "no module");
  }
  group->open = modules.size();
  RequestId first = 0;
  for (const auto& [gateway, module] : modules) {
    v1::RemoteRequest r = request;
    r.set_module_id(module);
    const RequestId id = send(gateway, std::move(r), Effect::changes_node, options_.answer_slack,
                              nullptr, nullptr, group);
    if (first == 0) first = id;
  }
  return first;
}

RemoteAccess::RequestId SurfaceRemote::set_node_id(RemoteTarget target, canopen::NodeId new_node,
                                                   Done done) {
  if (new_node < 1 || new_node > canopen::kMaxNodeId) {
    return refuse(std::move(done), errc(std::errc::invalid_argument),
                  "new node id " + std::to_string(new_node) + ": not 1..127");
  }
  v1::RemoteRequest request;
  request.mutable_nmt()->set_command(0xE0);
  request.mutable_nmt()->set_new_node(new_node);
  return route_and_send(target, false, std::move(request), Effect::changes_node,
                        options_.answer_slack + kBootWait, std::move(done));
}

RemoteAccess::RequestId SurfaceRemote::flash(RemoteTarget target, std::vector<std::uint8_t> image,
                                             std::function<void(const FlashProgress&)> progress,
                                             Done done) {
  v1::RemoteRequest request;
  request.mutable_flash()->set_image(image.data(), image.size());
  return route_and_send(target, false, std::move(request), Effect::changes_node,
                        options_.flash_limit, std::move(done), std::move(progress));
}

RemoteAccess::RequestId SurfaceRemote::lss(NetworkNumber net, std::string command,
                                           std::vector<std::uint32_t> args, Done done) {
  if (net == 0) {
    return refuse(std::move(done), errc(std::errc::permission_denied),
                  "LSS runs on a module's network, not on the default network 0");
  }
  v1::RemoteRequest request;
  request.mutable_lss()->set_command(std::move(command));
  for (std::uint32_t a : args) request.mutable_lss()->add_args(a);
  return route_and_send({net, 0}, true, std::move(request), Effect::changes_node,
                        options_.answer_slack + kLssWait, std::move(done));
}

void SurfaceRemote::cancel(RequestId id) {
  const auto it = pending_.find(id);
  if (it == pending_.end()) return;  // ended already (or never sent): its end stands
  v1::Payload payload;
  payload.mutable_remote_cancel()->set_request_id(id);
  surface_.send_to_gateway(it->second.gateway, payload.SerializeAsString());
  ++counters_.cancelled;
  finish(id, {errc(std::errc::operation_canceled), {}, "cancelled"});
}

void SurfaceRemote::nodes(NetworkNumber net,
                          std::function<void(std::vector<NodeRow>, std::error_code)> done) {
  auto group = std::make_shared<Group>();
  group->nodes_done = std::move(done);
  std::vector<std::pair<GatewayId, std::uint32_t>> asks;  // (gateway, module or 0: all)
  if (net != 0) {
    const std::optional<std::uint32_t> module = module_of_network(net);
    if (module) asks.emplace_back(*configured_owner_of_module(*module), *module);
  } else {
    for (std::size_t i = 0; i < gateways_.size(); ++i) {
      asks.emplace_back(static_cast<GatewayId>(i), 0);
    }
  }
  // A gateway that is down cannot be asked: its nodes are listed from the surface's own view of
  // them (the node events it sent), each lost, since no master reaches them now. The caller
  // tells its operator which gateway is down (networks()).
  std::erase_if(asks, [&](const auto& a) {
    if (connected(a.first)) return false;
    add_rows_of_down_gateway(a.first, a.second, group->rows);
    return true;
  });
  if (asks.empty()) {
    const std::error_code error = net != 0 && !module_of_network(net)
                                      ? errc(std::errc::no_such_device_or_address)
                                      : std::error_code{};
    sort_rows(group->rows);
    asio::post(executor_, [done = std::move(group->nodes_done), rows = std::move(group->rows),
                           error]() mutable { done(std::move(rows), error); });
    return;
  }
  group->open = asks.size();
  for (const auto& [gateway, module] : asks) {
    v1::RemoteRequest request;
    request.set_module_id(module);
    request.mutable_nodes();
    send(gateway, std::move(request), Effect::none, options_.answer_slack, nullptr, nullptr, group);
  }
}

void SurfaceRemote::add_rows_of_down_gateway(GatewayId gateway, std::uint32_t module_id,
                                             std::vector<NodeRow>& rows) const {
  const std::string name = gateway_name(gateway);
  surface_.node_states().for_each_node(
      gateway, [&](std::uint32_t module, std::uint32_t local, const SurfaceNodeStates::Node& n) {
        if (module_id != 0 && module != module_id) return;
        NodeRow row;
        row.net = network_of(module);
        row.module_id = module;
        row.gateway = name;
        row.local_node = static_cast<canopen::NodeId>(local);
        row.surface_node = static_cast<canopen::NodeId>(n.surface_node);
        row.nmt_state = static_cast<std::uint8_t>(n.nmt_state);
        row.in_loader = n.in_loader;
        row.lost = true;  // the heartbeat age, profile, kind and EMCY are the gateway's to know
        row.boot_count = n.boot_count;
        rows.push_back(std::move(row));
      });
}

void SurfaceRemote::on_remote_payload(GatewayId from, const v1::Payload& payload) {
  if (payload.has_remote_result()) return on_result(from, payload.remote_result());
  if (payload.has_remote_progress()) {
    const v1::RemoteProgress& p = payload.remote_progress();
    const auto it = pending_.find(p.request_id());
    if (it == pending_.end() || !ledger_.on_progress(p.request_id(), from, Clock::now())) {
      ++counters_.unknown_results;
      return;
    }
    arm_timer();
    if (it->second.progress) it->second.progress({p.step(), p.bytes_done(), p.bytes_total()});
  }
}

void SurfaceRemote::on_result(GatewayId from, const v1::RemoteResult& result) {
  const bool was_overdue = ledger_.overdue(result.request_id());
  using Result = RemoteRequestLedger::Result;
  const Result kind =
      result.cancelled() == v1::RemoteResult::BEFORE_START    ? Result::cancelled_not_started
      : result.cancelled() == v1::RemoteResult::WHILE_RUNNING ? Result::cancelled_running
                                                              : Result::done;
  const std::optional<RemoteRequestLedger::End> end =
      ledger_.on_result(result.request_id(), from, kind);
  if (!end || !pending_.contains(result.request_id())) {
    ++counters_.unknown_results;
    return;
  }
  ++counters_.results;
  if (*end != RemoteRequestLedger::End::answered) {
    // The gateway's answer to the surface's own cancel at the deadline: the client is told
    // whether the request ran, not that it was "cancelled", which it never asked for.
    return end_unanswered({result.request_id(), *end});
  }
  if (was_overdue) ++counters_.late_answers;
  Pending& p = pending_.at(result.request_id());
  if (p.group && p.group->nodes_done) {
    const std::string name = gateway_name(p.gateway);
    for (const v1::NodeRow& r : result.nodes()) {
      p.group->rows.push_back(row_of(r, network_of(r.module_id()), name));
    }
  }
  RemoteOutcome outcome;
  if (result.abort_code() != 0) outcome.error = canopen::abort_error(result.abort_code());
  // Not a failed transfer: a service the gateway does not offer there (309-3 error 100).
  if (result.not_supported()) outcome.error = std::make_error_code(std::errc::permission_denied);
  outcome.data.assign(result.data().begin(), result.data().end());
  outcome.detail = result.detail();
  finish(result.request_id(), std::move(outcome));
}

void SurfaceRemote::finish(RequestId id, RemoteOutcome outcome) {
  const auto it = pending_.find(id);
  if (it == pending_.end()) return;
  Pending p = std::move(it->second);
  pending_.erase(it);
  ledger_.cancel(id);  // ended here (stop(), cancel()): the ledger holds it no more
  if (!p.group) return post(std::move(p.done), std::move(outcome));
  Group& g = *p.group;
  if (!outcome.ok()) {
    ++g.failed;
    if (!g.first_error) {
      g.first_error = outcome.error;
      g.first_detail = outcome.detail;
    }
  }
  if (--g.open != 0) return;
  if (g.nodes_done) {
    sort_rows(g.rows);
    // Some gateway's rows are missing: say so, with the rows of the others.
    asio::post(executor_, [done = std::move(g.nodes_done), rows = std::move(g.rows),
                           error = g.first_error]() mutable { done(std::move(rows), error); });
    return;
  }
  post(std::move(g.done), {g.first_error, {}, g.first_detail});
}

void SurfaceRemote::arm_timer() {
  const std::optional<TimePoint> next = ledger_.next_deadline();
  if (!next || stopped_) return;
  const TimePoint first = *next;
  if (first >= armed_until_) return;  // a wake-up at or before it is set already
  armed_until_ = first;
  timer_.expires_at(first);
  timer_.async_wait(
      [this, alive = std::weak_ptr<int>(alive_)](const boost::system::error_code& ec) {
        if (ec || alive.expired()) return;
        armed_until_ = TimePoint::max();
        on_deadlines();
        arm_timer();
      });
}

// No answer in time: the surface stalled, the link was cut, or the gateway is gone. The request
// must never run late: a cancel follows it (the session delivers it after the request, whenever
// the link returns), and the gateway's answer, whichever it is, still ends the request for the
// ledger's resend window.
void SurfaceRemote::on_deadlines() {
  check_gateway_sessions();
  const RemoteRequestLedger::Due due = ledger_.on_time(Clock::now());
  for (const auto& [id, gateway] : due.cancels) {
    v1::Payload payload;
    payload.mutable_remote_cancel()->set_request_id(id);
    surface_.send_to_gateway(gateway, payload.SerializeAsString());
    ++counters_.overdue;
  }
  for (const RemoteRequestLedger::Ended& ended : due.ended) end_unanswered(ended);
}

void SurfaceRemote::end_unanswered(const RemoteRequestLedger::Ended& ended) {
  const auto it = pending_.find(ended.id);
  if (it == pending_.end()) return;
  const std::string gateway = "gateway '" + gateway_name(it->second.gateway) + "'";
  switch (ended.end) {
    case RemoteRequestLedger::End::outcome_unknown:
      ++counters_.outcome_unknown;
      return finish(ended.id, {make_error_code(RemoteEnd::outcome_unknown),
                               {},
                               "no answer from " + gateway +
                                   ", which may have executed it: read the object back"});
    case RemoteRequestLedger::End::timed_out:
      ++counters_.timed_out;
      return finish(ended.id, {errc(std::errc::timed_out), {}, "no answer from " + gateway});
    case RemoteRequestLedger::End::not_sent:
      return finish(ended.id,
                    {errc(std::errc::host_unreachable), {}, gateway + " is not connected"});
    case RemoteRequestLedger::End::answered:
      return;  // not unanswered
  }
}

RemoteRequestLedger::SessionId SurfaceRemote::session_of(GatewayId gateway) const {
  const auto& entries = surface_.gateway_table().gateways();
  return gateway < entries.size() && entries[gateway].connected ? entries[gateway].session_id : 0;
}

void SurfaceRemote::check_gateway_sessions() {
  if (ledger_.open_requests() == 0) return;
  for (std::size_t g = 0; g < gateways_.size(); ++g) {
    const auto gateway = static_cast<GatewayId>(g);
    for (const RemoteRequestLedger::Ended& ended :
         ledger_.on_gateway_session(gateway, session_of(gateway))) {
      end_unanswered(ended);
    }
  }
}

std::uint64_t SurfaceRemote::subscribe(std::function<void(const MonitorFrame&)> observer) {
  const std::uint64_t id = next_subscriber_++;
  subscribers_.emplace(id, std::move(observer));
  if (subscribers_.size() == 1 && !stopped_) {
    surface_.on_monitor_frames([this](std::span<const can::Frame> frames, std::uint32_t module_id,
                                      bool to_bus) { on_monitor(frames, module_id, to_bus); });
  }
  return id;
}

void SurfaceRemote::unsubscribe(std::uint64_t id) {
  const auto it = subscribers_.find(id);
  if (it == subscribers_.end()) return;
  // An observer that unsubscribes (itself or another) while being called: emptied, not erased
  // under the iteration; removed after it.
  it->second = nullptr;
  if (dispatching_) return;
  subscribers_.erase(it);
  // Nobody watches: the surface pays nothing again.
  if (subscribers_.empty()) surface_.on_monitor_frames(nullptr);
}

void SurfaceRemote::on_monitor(std::span<const can::Frame> frames, std::uint32_t module_id,
                               bool to_bus) {
  MonitorFrame m;
  m.time_us = unix_us_now();
  m.module_id = module_id;
  m.to_surface_bus = to_bus;
  dispatching_ = true;
  for (const can::Frame& frame : frames) {
    m.frame = frame;
    for (const auto& [id, observer] : subscribers_) {
      if (observer) observer(m);
    }
  }
  dispatching_ = false;
  counters_.monitor_frames += frames.size();
  std::erase_if(subscribers_, [](const auto& s) { return !s.second; });
  if (subscribers_.empty()) {
    // Not from inside the surface's call of the very hook being released.
    asio::post(executor_, [this, alive = std::weak_ptr<int>(alive_)] {
      if (!alive.expired() && subscribers_.empty()) surface_.on_monitor_frames(nullptr);
    });
  }
}

}  // namespace canbridge::bridge
