// The surface's remote access (bridge/surface_remote.hpp) on a real Surface, facing a scripted
// gateway over an in-memory link that answers RemoteRequests as each test says: routing by
// surface id on network 0 and by local id on a module's network, refusals at once (unknown node
// or network, gateway down), results, progress and node tables, the deadline that ends with
// timed_out and a RemoteCancel, cancel(), and the monitor feed in both directions; then end to
// end with a real Gateway running the transfer on its module bus.
#include "bridge/surface_remote.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
#include "backbone/session.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "bridge/gateway_claims.hpp"
#include "bridge/surface.hpp"
#include "can/virtual_bus.hpp"
#include "canopen/sdo_abort.hpp"
#include "routing/node_map.hpp"
#include "tests/bridge/loopback_roles.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::BusRecorder;
using test::run_until;

constexpr ModuleId kModule = 1;
constexpr ModuleId kOtherModule = 4;  // of "other-gw", never connected
constexpr canopen::NodeId kLocal = 2, kSurface = 5, kOtherSurface = 20;

BackboneTuning quick_tuning() {
  BackboneTuning t;
  t.session.keepalive_interval = 20ms;
  t.session.dead_after = 300ms;
  t.session.retransmit_timeout = 100ms;
  return t;
}

// A gateway's end of the backbone without a gateway behind it: it binds with claims for one
// node, records the RemoteRequests and RemoteCancels it gets and sends what the test gives it.
class ScriptedRemoteGateway {
 public:
  ScriptedRemoteGateway(std::string name, ModuleId module, canopen::NodeId local,
                        canopen::NodeId surface_id)
      : stream_(quick_tuning().session,
                backbone::PeerStream::Handlers{
                    [this](backbone::PayloadSink& sink) {
                      while (!out_.empty() && sink.room() > 0 &&
                             sink.reliable_room(out_.front().size())) {
                        sink.send_reliable(std::move(out_.front()));
                        out_.pop_front();
                      }
                    },
                    [this](std::span<const std::uint8_t> bytes, bool) { on_payload(bytes); },
                    [](const v1::Hello&) {}, [] {}}) {
    NodeMap map;
    EXPECT_TRUE(map.add_module(module, {{local, surface_id}}).empty());
    identity_.role = v1::Hello::ROLE_GATEWAY;
    identity_.expected_peer = v1::Hello::ROLE_SURFACE;
    identity_.name = std::move(name);
    identity_.module_ids = {module};
    identity_.session_id = backbone::random_session_id();
    identity_.application = encode_claims(claims_of(map));
  }

  void attach(std::shared_ptr<backbone::MessageLink> link) {
    link_ = backbone::SessionLink::create(std::move(link), identity_, quick_tuning().session,
                                          &stream_, nullptr, counters_);
    link_->start();
  }
  void close() {
    if (link_) link_->close();
  }
  bool up() const { return stream_.up(); }

  void send(const v1::Payload& payload) {
    out_.push_back(payload.SerializeAsString());
    stream_.wake();
  }
  void answer(std::uint64_t id, std::uint32_t abort_code, std::vector<std::uint8_t> data = {},
              std::vector<v1::NodeRow> rows = {}) {
    v1::Payload p;
    v1::RemoteResult& r = *p.mutable_remote_result();
    r.set_request_id(id);
    r.set_abort_code(abort_code);
    r.set_data(data.data(), data.size());
    for (const v1::NodeRow& row : rows) *r.add_nodes() = row;
    send(p);
  }

  std::vector<v1::RemoteRequest> requests;
  std::vector<std::uint64_t> cancels;
  std::uint64_t unexpected = 0;  // payloads of other kinds

 private:
  void on_payload(std::span<const std::uint8_t> bytes) {
    v1::Payload p;
    ASSERT_TRUE(p.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())));
    if (p.has_remote_request()) {
      requests.push_back(p.remote_request());
    } else if (p.has_remote_cancel()) {
      cancels.push_back(p.remote_cancel().request_id());
    } else {
      ++unexpected;
    }
  }

  backbone::SessionLink::Identity identity_;
  backbone::PeerStream stream_;
  backbone::SessionCounters counters_;
  std::shared_ptr<backbone::SessionLink> link_;
  std::deque<std::string> out_;
};

// What a Done saw; set once.
struct Seen {
  std::optional<RemoteOutcome> outcome;
  RemoteAccess::Done done() {
    return [this](RemoteOutcome o) {
      EXPECT_FALSE(outcome) << "done called twice";
      outcome = std::move(o);
    };
  }
};

class SurfaceRemoteTest : public ::testing::Test {
 protected:
  void SetUp() override {
    surface.start();
    connect();
    options.answer_slack = 100ms;
    options.resend_window = 200ms;
    remote =
        std::make_unique<SurfaceRemote>(io.get_executor(), surface, policy.gateways, options, 1000);
  }
  void TearDown() override {
    remote->stop();
    gateway.close();
    surface.stop();
    master.close();
    EXPECT_TRUE(run_until(io, [&] { return master.done(); }));
  }
  void connect() {
    auto pair = backbone::make_memory_link_pair(io.get_executor());
    surface.attach(pair.b);
    gateway.attach(pair.a);
    ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 1 && gateway.up(); }));
  }
  RemoteSdo read_1017(NetworkNumber net, canopen::NodeId node) {
    RemoteSdo sdo;
    sdo.target = {net, node};
    sdo.index = 0x1017;
    sdo.sub = 0;
    sdo.timeout = 50ms;
    return sdo;
  }

  boost::asio::io_context io{1};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  SurfacePolicy policy{
      {{"gw", {kModule}, {kSurface}}, {"other-gw", {kOtherModule}, {kOtherSurface}}}, false};
  Surface surface{io.get_executor(), "surface", surface_bus.connect("surface"), policy,
                  quick_tuning()};
  ScriptedRemoteGateway gateway{"gw", kModule, kLocal, kSurface};
  SurfaceRemoteOptions options;
  std::unique_ptr<SurfaceRemote> remote;
};

TEST_F(SurfaceRemoteTest, AnSdoReadOnNetworkZeroGoesToTheOwnerBySurfaceIdAndCompletesLater) {
  Seen seen;
  const auto id = remote->sdo(read_1017(0, kSurface), seen.done());
  EXPECT_EQ(id, 1000u);        // the first id given
  EXPECT_FALSE(seen.outcome);  // never inside the call
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  const v1::RemoteRequest& r = gateway.requests[0];
  EXPECT_EQ(r.request_id(), id);
  EXPECT_EQ(r.module_id(), kModule);
  EXPECT_EQ(r.surface_node(), kSurface);  // the gateway resolves the local id
  EXPECT_EQ(r.local_node(), 0u);
  EXPECT_EQ(r.timeout_ms(), 50u);
  ASSERT_TRUE(r.has_sdo());
  EXPECT_TRUE(r.sdo().upload());
  EXPECT_EQ(r.sdo().index(), 0x1017u);
  gateway.answer(id, 0, {0xE8, 0x03});
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_TRUE(seen.outcome->ok()) << seen.outcome->error.message();
  EXPECT_EQ(seen.outcome->data, (std::vector<std::uint8_t>{0xE8, 0x03}));
  EXPECT_EQ(remote->open_requests(), 0u);
  EXPECT_EQ(remote->counters().results, 1u);
}

TEST_F(SurfaceRemoteTest, AWriteOnAModuleNetworkUsesTheLocalIdAndReportsTheAbort) {
  RemoteSdo sdo = read_1017(kModule + 1, kLocal);  // default: module id + 1
  sdo.upload = false;
  sdo.data = {0x64, 0x00};
  sdo.block_size = 16;
  Seen seen;
  const auto id = remote->sdo(sdo, seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  const v1::RemoteRequest& r = gateway.requests[0];
  EXPECT_EQ(r.module_id(), kModule);
  EXPECT_EQ(r.local_node(), kLocal);
  EXPECT_EQ(r.surface_node(), 0u);
  EXPECT_FALSE(r.sdo().upload());
  EXPECT_EQ(r.sdo().data(), std::string("\x64\x00", 2));
  EXPECT_EQ(r.sdo().block_size(), 16u);
  gateway.answer(id, 0x06020000);
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_EQ(seen.outcome->error, canopen::abort_error(0x06020000));
}

TEST_F(SurfaceRemoteTest, ConfiguredNetworkNumbersReplaceTheDefault) {
  remote->stop();
  options.networks = {{kModule, 10}};
  remote = std::make_unique<SurfaceRemote>(io.get_executor(), surface, policy.gateways, options);
  Seen on_10, on_2;
  remote->sdo(read_1017(10, kLocal), on_10.done());
  remote->sdo(read_1017(2, kLocal), on_2.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1 && on_2.outcome; }));
  EXPECT_EQ(gateway.requests[0].module_id(), kModule);
  EXPECT_EQ(on_2.outcome->error, std::make_error_code(std::errc::no_such_device_or_address));
  const std::vector<NetworkInfo> nets = remote->networks();
  ASSERT_EQ(nets.size(), 3u);
  EXPECT_EQ(nets[0].net, 0u);
  EXPECT_EQ(nets[1].net, kOtherModule + 1);
  EXPECT_FALSE(nets[1].connected);
  EXPECT_EQ(nets[2].net, 10u);
  EXPECT_EQ(nets[2].gateway, "gw");
  EXPECT_TRUE(nets[2].connected);
  // on_10's request is never answered: stopping completes it, while on_10 still exists.
  remote->stop();
  EXPECT_TRUE(run_until(io, [&] { return on_10.outcome.has_value(); }));
}

TEST_F(SurfaceRemoteTest, UnknownNodesAndNetworksAreRefusedAtOnceWithoutARequest) {
  Seen unknown_node, unknown_net, node_zero, bad_id;
  remote->sdo(read_1017(0, 99), unknown_node.done());
  remote->sdo(read_1017(77, 1), unknown_net.done());
  remote->sdo(read_1017(0, 0), node_zero.done());
  remote->set_node_id({0, kSurface}, 0, bad_id.done());
  EXPECT_FALSE(unknown_node.outcome);  // later, not inside the call
  ASSERT_TRUE(run_until(io, [&] {
    return unknown_node.outcome && unknown_net.outcome && node_zero.outcome && bad_id.outcome;
  }));
  const auto nxio = std::make_error_code(std::errc::no_such_device_or_address);
  EXPECT_EQ(unknown_node.outcome->error, nxio);
  EXPECT_EQ(unknown_net.outcome->error, nxio);
  EXPECT_EQ(node_zero.outcome->error, nxio);
  EXPECT_EQ(bad_id.outcome->error, std::make_error_code(std::errc::invalid_argument));
  EXPECT_TRUE(gateway.requests.empty());
  EXPECT_EQ(remote->counters().refused_at_once, 4u);
}

TEST_F(SurfaceRemoteTest, AGatewayThatIsDownIsUnreachableAtOnce) {
  // "other-gw" never connected: its surface id and its module's network.
  Seen never_node, never_net;
  remote->sdo(read_1017(0, kOtherSurface), never_node.done());
  remote->nmt({kOtherModule + 1, 0}, NmtCommand::start, never_net.done());
  // "gw" connected once, now down: its node stays its own, unreachable.
  gateway.close();
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 0; }));
  Seen down;
  remote->sdo(read_1017(0, kSurface), down.done());
  ASSERT_TRUE(
      run_until(io, [&] { return never_node.outcome && never_net.outcome && down.outcome; }));
  const auto unreachable = std::make_error_code(std::errc::host_unreachable);
  EXPECT_EQ(never_node.outcome->error, unreachable) << never_node.outcome->detail;
  EXPECT_EQ(never_net.outcome->error, unreachable) << never_net.outcome->detail;
  EXPECT_EQ(down.outcome->error, unreachable) << down.outcome->detail;
  EXPECT_NE(down.outcome->detail.find("'gw'"), std::string::npos) << down.outcome->detail;
  connect();
  EXPECT_TRUE(gateway.requests.empty());
}

// Past its deadline a request gets a cancel and still waits the resend window (200 ms here) for
// the gateway's answer; a read that gets none has timed out, and a late answer is dropped.
TEST_F(SurfaceRemoteTest, NoAnswerInTimeSendsACancelThenAReadEndsWithTimedOut) {
  Seen seen;
  const auto started = std::chrono::steady_clock::now();
  const auto id = remote->sdo(read_1017(0, kSurface), seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.cancels.size() == 1; }));
  EXPECT_EQ(gateway.cancels[0], id);
  ASSERT_EQ(gateway.requests.size(), 1u);                        // the request came first
  EXPECT_GE(std::chrono::steady_clock::now() - started, 150ms);  // SDO timeout + answer_slack
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_GE(std::chrono::steady_clock::now() - started, 350ms);  // ... + resend_window
  EXPECT_EQ(seen.outcome->error, std::make_error_code(std::errc::timed_out));
  EXPECT_NE(seen.outcome->detail.find("no answer from gateway 'gw'"), std::string::npos);
  // The gateway's late answer is dropped, counted.
  gateway.answer(id, 0, {1});
  ASSERT_TRUE(run_until(io, [&] { return remote->counters().unknown_results == 1; }));
  EXPECT_EQ(remote->counters().timed_out, 1u);
  EXPECT_EQ(remote->counters().overdue, 1u);
}

// Issue 27: a write whose answer never comes may have been executed: never "timed out".
TEST_F(SurfaceRemoteTest, AWriteNeverAnsweredEndsWithOutcomeUnknown) {
  RemoteSdo sdo = read_1017(0, kSurface);
  sdo.upload = false;
  sdo.data = {0x64, 0x00};
  Seen seen;
  remote->sdo(sdo, seen.done());
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_EQ(seen.outcome->error, make_error_code(RemoteEnd::outcome_unknown));
  EXPECT_NE(seen.outcome->detail.find("read the object back"), std::string::npos);
  EXPECT_EQ(remote->counters().outcome_unknown, 1u);
  EXPECT_EQ(remote->counters().timed_out, 0u);
}

// Issue 27: the gateway did the write, its answer came after the deadline (a stalled surface,
// a cut link): that answer is the client's, not a time-out.
TEST_F(SurfaceRemoteTest, AnAnswerAfterTheDeadlineWithinTheResendWindowIsTheAnswer) {
  RemoteSdo sdo = read_1017(0, kSurface);
  sdo.upload = false;
  sdo.data = {0x64, 0x00};
  Seen seen;
  const auto id = remote->sdo(sdo, seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.cancels.size() == 1; }));
  EXPECT_FALSE(seen.outcome);
  gateway.answer(id, 0);
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_TRUE(seen.outcome->ok()) << seen.outcome->error.message();
  EXPECT_EQ(remote->counters().late_answers, 1u);
}

// The gateway's answer to the deadline's cancel says whether the write ran.
TEST_F(SurfaceRemoteTest, TheCancelsAnswerTellsATimeOutFromAnUnknownOutcome) {
  RemoteSdo sdo = read_1017(0, kSurface);
  sdo.upload = false;
  sdo.data = {0x64, 0x00};
  Seen queued, running;
  const auto queued_id = remote->sdo(sdo, queued.done());
  const auto running_id = remote->sdo(sdo, running.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.cancels.size() == 2; }));
  for (auto [id, when] : {std::pair{queued_id, v1::RemoteResult::BEFORE_START},
                          std::pair{running_id, v1::RemoteResult::WHILE_RUNNING}}) {
    v1::Payload p;
    p.mutable_remote_result()->set_request_id(id);
    p.mutable_remote_result()->set_abort_code(0x08000021);
    p.mutable_remote_result()->set_detail("cancelled");
    p.mutable_remote_result()->set_cancelled(when);
    gateway.send(p);
  }
  ASSERT_TRUE(run_until(io, [&] { return queued.outcome && running.outcome; }));
  EXPECT_EQ(queued.outcome->error, std::make_error_code(std::errc::timed_out));
  EXPECT_EQ(running.outcome->error, make_error_code(RemoteEnd::outcome_unknown));
}

// A long transfer the gateway reports progress on never times out at the surface, however long
// it runs beyond timeout + answer_slack (150 ms here); once the reports stop, it does.
TEST_F(SurfaceRemoteTest, ProgressReportsKeepALongTransferWaiting) {
  Seen seen;
  const auto id = remote->sdo(read_1017(0, kSurface), seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  const auto started = std::chrono::steady_clock::now();
  auto reported = started;
  std::uint64_t done_bytes = 0;
  // Reports every 50 ms for 600 ms, as a gateway running a 64 KiB segmented upload would.
  ASSERT_TRUE(run_until(io, [&] {
    const auto now = std::chrono::steady_clock::now();
    if (now - reported >= 50ms) {
      reported = now;
      v1::Payload p;
      p.mutable_remote_progress()->set_request_id(id);
      p.mutable_remote_progress()->set_step("upload");
      p.mutable_remote_progress()->set_bytes_done(done_bytes += 700);
      gateway.send(p);
    }
    return seen.outcome.has_value() || now - started >= 600ms;
  }));
  EXPECT_FALSE(seen.outcome.has_value()) << seen.outcome->detail;
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_EQ(seen.outcome->error, std::make_error_code(std::errc::timed_out));
}

TEST_F(SurfaceRemoteTest, CancelEndsTheRequestAndTellsTheGateway) {
  Seen seen;
  const auto id = remote->sdo(read_1017(0, kSurface), seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  remote->cancel(id);
  EXPECT_FALSE(seen.outcome);
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome && gateway.cancels.size() == 1; }));
  EXPECT_EQ(seen.outcome->error, std::make_error_code(std::errc::operation_canceled));
  EXPECT_EQ(gateway.cancels[0], id);
}

TEST_F(SurfaceRemoteTest, FlashProgressReachesTheCallerUntilTheResult) {
  std::vector<FlashProgress> steps;
  Seen seen;
  const auto id = remote->flash(
      {kModule + 1, kLocal}, {1, 2, 3, 4}, [&](const FlashProgress& p) { steps.push_back(p); },
      seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  EXPECT_EQ(gateway.requests[0].flash().image(), std::string("\x01\x02\x03\x04", 4));
  v1::Payload p;
  p.mutable_remote_progress()->set_request_id(id);
  p.mutable_remote_progress()->set_step("download");
  p.mutable_remote_progress()->set_bytes_done(2);
  p.mutable_remote_progress()->set_bytes_total(4);
  gateway.send(p);
  ASSERT_TRUE(run_until(io, [&] { return steps.size() == 1; }));
  EXPECT_EQ(steps[0].step, "download");
  EXPECT_EQ(steps[0].bytes_done, 2u);
  EXPECT_EQ(steps[0].bytes_total, 4u);
  gateway.answer(id, 0);
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  EXPECT_TRUE(seen.outcome->ok());
}

TEST_F(SurfaceRemoteTest, NodesMergesTheRowsOfConnectedGatewaysWithTheirNetworks) {
  std::optional<std::vector<NodeRow>> rows;
  std::error_code error;
  remote->nodes(0, [&](std::vector<NodeRow> r, std::error_code ec) {
    rows = std::move(r);
    error = ec;
  });
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1; }));
  EXPECT_TRUE(gateway.requests[0].has_nodes());
  EXPECT_EQ(gateway.requests[0].module_id(), 0u);  // every module of the gateway
  v1::NodeRow row;
  row.set_module_id(kModule);
  row.set_local_node(kLocal);
  row.set_surface_node(kSurface);
  row.set_profile("cia301");
  row.set_nmt_state(5);
  row.set_heartbeat_age_ms(120);
  row.set_last_emcy_code(0x8130);
  row.set_last_emcy_register(0x11);
  row.set_last_emcy_age_ms(3000);
  row.set_boot_count(2);
  gateway.answer(gateway.requests[0].request_id(), 0, {}, {row});
  ASSERT_TRUE(run_until(io, [&] { return rows.has_value(); }));
  // "other-gw" is down and never reported a node: nothing of it to list, and no failure.
  EXPECT_FALSE(error) << error.message();
  ASSERT_EQ(rows->size(), 1u);
  const NodeRow& r = (*rows)[0];
  EXPECT_EQ(r.net, kModule + 1);
  EXPECT_EQ(r.gateway, "gw");
  EXPECT_EQ(r.local_node, kLocal);
  EXPECT_EQ(r.surface_node, kSurface);
  EXPECT_EQ(r.nmt_state, 5u);
  EXPECT_EQ(r.heartbeat_age, 120ms);
  EXPECT_EQ(r.last_emcy_code, 0x8130u);
  EXPECT_EQ(r.last_emcy_register, 0x11u);
  EXPECT_EQ(r.boot_count, 2u);
}

// `canbridge nodes` with a gateway down exited 5 "Lost connection" while the surface knew its
// nodes: they are listed from the surface's own table, lost, without asking anyone.
TEST_F(SurfaceRemoteTest, NodesOfAGatewayThatIsDownComeFromTheSurfacesOwnTableLost) {
  v1::Payload events;
  v1::NodeEvent& e = *events.mutable_node_events()->add_events();
  e.set_kind(v1::NodeEvent::BOOTED);
  e.set_module_id(kModule);
  e.set_local_node(kLocal);
  e.set_surface_node(kSurface);
  e.set_nmt_state(0x7F);
  e.set_boot_count(3);
  gateway.send(events);
  ASSERT_TRUE(run_until(io, [&] { return surface.node_states().size() == 1; }));
  gateway.close();
  ASSERT_TRUE(run_until(io, [&] { return surface.gateways_ready() == 0; }));
  for (const NetworkNumber net : {NetworkNumber{0}, NetworkNumber{kModule + 1}}) {
    std::optional<std::vector<NodeRow>> rows;
    std::error_code error;
    remote->nodes(net, [&](std::vector<NodeRow> r, std::error_code ec) {
      rows = std::move(r);
      error = ec;
    });
    ASSERT_TRUE(run_until(io, [&] { return rows.has_value(); }));
    EXPECT_FALSE(error) << error.message();
    ASSERT_EQ(rows->size(), 1u) << "net " << net;
    const NodeRow& r = (*rows)[0];
    EXPECT_EQ(r.net, kModule + 1);
    EXPECT_EQ(r.gateway, "gw");
    EXPECT_EQ(r.local_node, kLocal);
    EXPECT_EQ(r.surface_node, kSurface);
    EXPECT_EQ(r.boot_count, 3u);
    EXPECT_TRUE(r.lost);
    EXPECT_FALSE(r.heartbeat_age);
  }
  connect();
  EXPECT_TRUE(gateway.requests.empty()) << "a gateway that was down was asked";
}

TEST_F(SurfaceRemoteTest, NmtToEveryNodeOfNetworkZeroTellsEveryModule) {
  Seen seen;
  remote->nmt({0, 0}, NmtCommand::reset_node, seen.done());
  ASSERT_TRUE(run_until(io, [&] { return gateway.requests.size() == 1 && !seen.outcome; }));
  EXPECT_EQ(gateway.requests[0].nmt().command(), 0x81u);
  EXPECT_EQ(gateway.requests[0].local_node(), 0u);
  gateway.answer(gateway.requests[0].request_id(), 0);
  ASSERT_TRUE(run_until(io, [&] { return seen.outcome.has_value(); }));
  // "other-gw"'s module could not be told.
  EXPECT_EQ(seen.outcome->error, std::make_error_code(std::errc::host_unreachable));
}

TEST_F(SurfaceRemoteTest, TheMonitorSeesFramesBothWaysOnlyWhileSubscribed) {
  std::vector<MonitorFrame> seen;
  const auto sub = remote->subscribe([&](const MonitorFrame& f) { seen.push_back(f); });
  // From the master: read off the surface bus (module 0).
  const Frame sync = Frame::standard(0x080, {});
  ASSERT_TRUE(master.send(sync));
  // From the gateway's module: written to the surface bus under its module.
  v1::Payload p;
  FrameBatchBuilder builder;
  builder.start(*p.mutable_frames(), kModule);
  const Frame heartbeat = Frame::standard(0x700u + kSurface, {0x05});
  builder.append(*p.mutable_frames(), heartbeat);
  gateway.send(p);
  ASSERT_TRUE(run_until(io, [&] { return seen.size() == 2 && master.saw(heartbeat); }));
  const auto& from_master = seen[0].frame == sync ? seen[0] : seen[1];
  const auto& to_master = seen[0].frame == sync ? seen[1] : seen[0];
  EXPECT_EQ(from_master.module_id, 0u);
  EXPECT_FALSE(from_master.to_surface_bus);
  EXPECT_EQ(to_master.frame, heartbeat);
  EXPECT_EQ(to_master.module_id, kModule);
  EXPECT_TRUE(to_master.to_surface_bus);
  EXPECT_GT(to_master.time_us, 1'600'000'000'000'000);  // Unix time in µs
  remote->unsubscribe(sub);
  ASSERT_TRUE(master.send(sync));
  ASSERT_TRUE(run_until(io, [&] { return surface.counters().from_bus == 2; }));
  EXPECT_EQ(seen.size(), 2u);
  EXPECT_EQ(remote->counters().monitor_frames, 2u);
}

// The real gateway behind the surface: it runs the SDO transfer on its module bus (the node's
// answer never reaches the surface bus), found by surface id on network 0 and by local id on the
// module's network.
TEST(SurfaceRemoteEndToEnd, TheGatewayRunsTheSdoReadOnBothNetworks) {
  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module"};
  can::VirtualBus surface_bus{io.get_executor(), "surface-bus"};
  BusRecorder master{io, surface_bus.connect("master")};
  BusRecorder node{io, module_bus.connect("node")};
  // The node answers every expedited upload of 1017h with 1000 (ms).
  std::size_t answered = 0;
  node.on_frames = [&] {
    for (; answered < node.frames.size(); ++answered) {
      const Frame& f = node.frames[answered];
      if (f.id == 0x600u + kLocal && f.data[0] == 0x40 && f.data[1] == 0x17 && f.data[2] == 0x10) {
        node.send(Frame::standard(0x580u + kLocal, {0x4B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0, 0}));
      }
    }
  };
  NodeMap map;
  ASSERT_TRUE(map.add_module(kModule, {{kLocal, kSurface}}).empty());
  std::vector<GatewayModule> modules(1);
  modules[0].id = kModule;
  modules[0].bus = module_bus.connect("gateway");
  Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules), quick_tuning());
  const SurfacePolicy policy{{{"gw", {kModule}, {kSurface}}}, false};
  Surface surface(io.get_executor(), "surface", surface_bus.connect("surface"), policy,
                  quick_tuning());
  ASSERT_TRUE(start_linked_in_memory(io, surface, gateway));
  SurfaceRemote remote(io.get_executor(), surface, policy.gateways);
  std::vector<Seen> seen(2);
  RemoteSdo sdo;
  sdo.index = 0x1017;
  sdo.target = {0, kSurface};
  remote.sdo(sdo, seen[0].done());
  sdo.target = {kModule + 1, kLocal};
  remote.sdo(sdo, seen[1].done());
  ASSERT_TRUE(run_until(io, [&] { return seen[0].outcome && seen[1].outcome; }))
      << gateway.stats_line();
  for (const Seen& s : seen) {
    EXPECT_TRUE(s.outcome->ok()) << s.outcome->error.message() << " " << s.outcome->detail;
    EXPECT_EQ(s.outcome->data, (std::vector<std::uint8_t>{0xE8, 0x03}));
  }
  EXPECT_EQ(node.count(0x600u + kLocal), 2u);
  EXPECT_EQ(master.count(0x580u + kSurface), 0u);  // the gateway's own transfer stays local
  remote.stop();
  gateway.stop();
  surface.stop();
  master.close();
  node.close();
  EXPECT_TRUE(run_until(io, [&] { return master.done() && node.done(); }));
}

}  // namespace
}  // namespace canbridge::bridge
