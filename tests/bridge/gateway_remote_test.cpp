// The services a gateway runs for the surface (GatewayRemote), driven directly with simulated
// nodes on one module bus and a virtual clock: SDO in every mode, one transfer per node with
// queueing, cancel, the collision rule with a master's transfer, NMT, set-node-id, the node list,
// firmware download and repeated ids.
#include "bridge/gateway_remote.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <set>
#include <string>
#include <vector>

#include "backbone/memory_link.hpp"
#include "backbone/session.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "bridge/gateway.hpp"
#include "can/virtual_bus.hpp"
#include "routing/rename_follower.hpp"
#include "sim/firmware_image.hpp"
#include "sim/sim_node.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"
#include "tests/support/fake_payload_sink.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using canopen::NodeId;
using TimePoint = GatewayRemote::TimePoint;

const TimePoint t0 = TimePoint{} + 1h;
constexpr std::uint32_t kLocalControl = 0x08000021;
constexpr std::uint16_t kDomain = 0x2000;

std::string pattern(std::size_t size) {
  std::string s(size, '\0');
  for (std::size_t i = 0; i < size; ++i) s[i] = static_cast<char>(i * 7 + 3);
  return s;
}

sim::NodeSpec node_spec(NodeId id, sim::NodeKind kind = sim::NodeKind::cia301) {
  sim::NodeSpec spec;
  spec.kind = kind;
  spec.node_id = id;
  spec.heartbeat_ms = 0;  // quiet: the tests drive every frame
  if (kind == sim::NodeKind::cia301) {
    spec.objects.push_back({kDomain, 0, sim::DataType::domain, sim::Access::rw, {}});
  }
  return spec;
}

v1::RemoteRequest sdo_request(std::uint64_t id, NodeId node, bool upload, std::uint16_t index,
                              std::string data = {}, std::uint32_t block = 0) {
  v1::RemoteRequest r;
  r.set_request_id(id);
  r.set_module_id(1);
  r.set_local_node(node);
  v1::SdoOp& op = *r.mutable_sdo();
  op.set_upload(upload);
  op.set_index(index);
  op.set_subindex(0);
  op.set_data(std::move(data));
  op.set_block_size(block);
  return r;
}

v1::RemoteRequest nmt_request(std::uint64_t id, NodeId node, std::uint32_t command,
                              NodeId new_node = 0) {
  v1::RemoteRequest r;
  r.set_request_id(id);
  r.set_module_id(1);
  r.set_local_node(node);
  r.mutable_nmt()->set_command(command);
  r.mutable_nmt()->set_new_node(new_node);
  return r;
}

v1::RemoteCancel cancel_of(std::uint64_t id) {
  v1::RemoteCancel c;
  c.set_request_id(id);
  return c;
}

bool is_sdo_response_of(const Frame& f, NodeId node) {
  return f.id == 0x580u + node;
}

// One module bus (module 1, cia301) with simulated nodes, the gateway's node table and the core.
// Frames the core writes reach every node at once; the nodes' answers go to the table and the
// core, and those the core does not take are what the surface would get.
class Rig {
 public:
  explicit Rig(std::vector<sim::NodeSpec> specs, GatewayRemoteOptions options = {},
               IdProfile profile = IdProfile::cia301, bool lss = false) {
    std::vector<std::pair<NodeId, NodeId>> pairs;
    for (const auto& s : specs) pairs.emplace_back(s.node_id, s.node_id + 10);
    EXPECT_TRUE(map.add_module(1, pairs, profile).empty());
    table.add_module(profile);
    core = std::make_unique<GatewayRemote>(map, table, std::vector<GatewayRemote::Module>{{1, lss}},
                                           options, [this](std::size_t m, NodeId n) {
                                             return master_open.contains({m, n});
                                           });
    for (const auto& s : specs) {
      nodes.push_back(std::make_unique<sim::SimNode>(s));
      for (const Frame& f : nodes.back()->boot(now)) from_node(f);
    }
    surface.clear();
  }

  void request(const v1::RemoteRequest& r, bool run_bus = true) {
    core->on_request(r, now);
    if (run_bus) run();
    collect();
  }
  void cancel(std::uint64_t id, bool run_bus = true) {
    core->on_cancel(cancel_of(id), now);
    if (run_bus) run();
    collect();
  }
  // Writes what the core queued for the bus, and everything the nodes answer, until quiet.
  void run() {
    for (int round = 0; round < 100000; ++round) {
      std::vector<Frame> out;
      for (auto& b : core->bus_frames()) out.insert(out.end(), b.frames.begin(), b.frames.end());
      core->bus_frames().clear();
      if (out.empty()) break;
      for (const Frame& f : out) to_bus(f);
    }
    collect();
  }
  void advance(std::chrono::milliseconds d) {
    now += d;
    for (auto& n : nodes) {
      for (const Frame& f : n->on_tick(now)) from_node(f);
    }
    table.tick(now, events);
    deliver_events();
    core->tick(now);
    run();
  }
  void to_bus(const Frame& f) {
    written.push_back(f);
    if (f.id == 0) table.on_nmt_to_bus(0, f, now, events);  // as the gateway's on_written
    deliver_events();
    for (auto& n : nodes) {
      for (const Frame& reply : n->on_frame(f, now)) from_node(reply);
    }
  }
  void from_node(const Frame& f) {
    table.on_bus_frame(0, f, now, events);
    deliver_events();
    if (!core->on_bus_frame(0, f, now)) surface.push_back(f);
  }
  void deliver_events() {
    std::vector<NodeEvent> e;
    e.swap(events);
    for (NodeEvent& ev : e) {
      follow_rename(map, ev);  // as the gateway: the live map first, then the core
      core->on_node_event(ev, now);
    }
  }
  void collect() {
    while (core->has_results()) {
      results.push_back(core->front_result());
      core->pop_result();
    }
  }
  const v1::RemoteResult* result(std::uint64_t id) const {
    const v1::RemoteResult* found = nullptr;
    for (const auto& r : results) {
      if (r.request_id() == id) {
        EXPECT_EQ(found, nullptr) << "two results for request " << id;
        found = &r;
      }
    }
    return found;
  }
  sim::SimNode& node(NodeId id) {
    for (auto& n : nodes) {
      if (n->id() == id) return *n;
    }
    throw std::out_of_range("no node");
  }

  NodeMap map;
  NodeTable table;
  std::set<std::pair<std::size_t, NodeId>> master_open;
  std::unique_ptr<GatewayRemote> core;
  std::vector<std::unique_ptr<sim::SimNode>> nodes;
  std::vector<NodeEvent> events;
  TimePoint now = t0;
  std::vector<Frame> written;  // by the core
  std::vector<Frame> surface;  // node frames the core did not take
  std::vector<v1::RemoteResult> results;
};

TEST(GatewayRemote, SdoReadsAndWritesInEveryModeAnswerOnceAndKeepTheirResponsesOffTheSurface) {
  Rig rig({node_spec(5)});
  std::uint64_t id = 1;
  struct Mode {
    std::size_t size;
    std::uint32_t block;
  };
  for (const Mode mode : {Mode{3, 0}, Mode{100, 0}, Mode{1000, 16}, Mode{5, 127}}) {
    const std::string value = pattern(mode.size);
    const std::uint64_t write = id++;
    const std::uint64_t read = id++;
    rig.request(sdo_request(write, 5, false, kDomain, value, mode.block));
    rig.request(sdo_request(read, 5, true, kDomain, {}, mode.block));
    ASSERT_NE(rig.result(write), nullptr) << mode.size;
    EXPECT_EQ(rig.result(write)->abort_code(), 0u) << rig.result(write)->detail();
    ASSERT_NE(rig.result(read), nullptr);
    EXPECT_EQ(rig.result(read)->abort_code(), 0u) << rig.result(read)->detail();
    EXPECT_EQ(rig.result(read)->data(), value) << "size " << mode.size << " block " << mode.block;
  }
  // Expedited read of the device type; a missing object answers with the node's abort.
  rig.request(sdo_request(id, 5, true, 0x1000));
  ASSERT_NE(rig.result(id), nullptr);
  EXPECT_EQ(rig.result(id)->data().size(), 4u);
  rig.request(sdo_request(++id, 5, true, 0x6543));
  ASSERT_NE(rig.result(id), nullptr);
  EXPECT_EQ(rig.result(id)->abort_code(), 0x06020000u);
  EXPECT_EQ(rig.results.size(), id);
  for (const Frame& f : rig.surface) EXPECT_FALSE(is_sdo_response_of(f, 5)) << f.id;
  EXPECT_GT(rig.core->counters().sdo_frames_taken, 10u);
  EXPECT_EQ(rig.core->pending(), 0u);
}

TEST(GatewayRemote, OneTransferPerNodeInOrderWhileOtherNodesRunAtOnce) {
  Rig rig({node_spec(5), node_spec(6)});
  rig.request(sdo_request(1, 5, false, kDomain, pattern(50)), false);
  rig.request(sdo_request(2, 5, true, kDomain), false);
  rig.request(sdo_request(3, 5, false, kDomain, pattern(20)), false);
  rig.request(sdo_request(4, 6, true, 0x1000), false);
  // Before the bus runs: one initiate for each node, nothing more.
  std::size_t to5 = 0, to6 = 0;
  for (auto& b : rig.core->bus_frames()) {
    for (const Frame& f : b.frames) {
      to5 += f.id == 0x605;
      to6 += f.id == 0x606;
    }
  }
  EXPECT_EQ(to5, 1u);
  EXPECT_EQ(to6, 1u);
  EXPECT_TRUE(rig.core->transferring(0, 5));
  EXPECT_TRUE(rig.core->transferring(0, 6));
  EXPECT_FALSE(rig.core->transferring(0, 7));
  rig.run();
  ASSERT_EQ(rig.results.size(), 4u);
  std::vector<std::uint64_t> node5;
  for (const auto& r : rig.results) {
    EXPECT_EQ(r.abort_code(), 0u) << r.detail();
    if (r.request_id() != 4) node5.push_back(r.request_id());
  }
  EXPECT_EQ(node5, (std::vector<std::uint64_t>{1, 2, 3}));
  // Request 2 read what request 1 wrote: it ran after it, not beside it.
  EXPECT_EQ(rig.result(2)->data(), pattern(50));
  EXPECT_FALSE(rig.core->transferring(0, 5));
}

TEST(GatewayRemote, CancelRemovesAQueuedRequestAndAbortsARunningOneEachAnsweredOnce) {
  Rig rig({node_spec(5)});
  rig.request(sdo_request(1, 5, true, kDomain), false);
  rig.request(sdo_request(2, 5, true, 0x1000), false);
  rig.core->bus_frames().clear();  // the initiate of 1 is lost: the node never answers it
  rig.cancel(2);
  ASSERT_NE(rig.result(2), nullptr);
  EXPECT_EQ(rig.result(2)->abort_code(), kLocalControl);
  EXPECT_EQ(rig.result(2)->detail(), "cancelled");
  // Taken off the queue: the surface may tell its client it never ran.
  EXPECT_EQ(rig.result(2)->cancelled(), v1::RemoteResult::BEFORE_START);
  EXPECT_EQ(rig.results.size(), 1u);
  rig.cancel(1);
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), kLocalControl);
  EXPECT_EQ(rig.result(1)->detail(), "cancelled");
  // Stopped on the bus: what it wrote before stays written, the outcome is not "never ran".
  EXPECT_EQ(rig.result(1)->cancelled(), v1::RemoteResult::WHILE_RUNNING);
  // The node was told: an SDO abort 0x08000021 on its request channel.
  ASSERT_FALSE(rig.written.empty());
  const Frame& abort = rig.written.back();
  EXPECT_EQ(abort.id, 0x605u);
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(abort.data[4] | abort.data[5] << 8 | abort.data[6] << 16 | abort.data[7] << 24,
            static_cast<int>(kLocalControl));
  // Nothing runs afterwards, and a late cancel or timeout adds no result.
  rig.cancel(1);
  rig.advance(5s);
  EXPECT_EQ(rig.results.size(), 2u);
  EXPECT_EQ(rig.core->counters().cancelled, 2u);
  EXPECT_EQ(rig.core->pending(), 0u);
}

TEST(GatewayRemote, AMastersOpenTransferMakesTheGatewayWaitThenRun) {
  Rig rig({node_spec(5)});
  rig.master_open.insert({0, 5});
  rig.request(sdo_request(1, 5, true, 0x1000));
  EXPECT_TRUE(rig.written.empty());
  EXPECT_FALSE(rig.core->transferring(0, 5));  // the master's frames still reach the node
  rig.advance(500ms);
  EXPECT_TRUE(rig.results.empty());
  rig.master_open.clear();  // the master's transfer ended
  rig.advance(1ms);
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0u);
  EXPECT_EQ(rig.core->counters().waited_for_master, 1u);
}

TEST(GatewayRemote, AMasterTransferThatOutlastsTheTimeoutEndsTheRequestWithLocalControl) {
  Rig rig({node_spec(5)});
  rig.master_open.insert({0, 5});
  v1::RemoteRequest r = sdo_request(1, 5, true, 0x1000);
  r.set_timeout_ms(300);
  rig.request(r);
  ASSERT_EQ(rig.core->next_deadline(), t0 + 300ms);
  rig.advance(299ms);
  EXPECT_TRUE(rig.results.empty());
  rig.advance(1ms);
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), kLocalControl);
  EXPECT_TRUE(rig.written.empty());  // never touched the node's channel
}

TEST(GatewayRemote, NmtToOneNodeAndToAllIsWrittenAndAnsweredAtOnce) {
  Rig rig({node_spec(5), node_spec(6)});
  rig.request(nmt_request(1, 5, 0x01));
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0u);
  EXPECT_EQ(rig.node(5).state(), canopen::NmtState::operational);
  EXPECT_EQ(rig.node(6).state(), canopen::NmtState::pre_operational);
  rig.request(nmt_request(2, 0, 0x02));
  ASSERT_NE(rig.result(2), nullptr);
  EXPECT_EQ(rig.node(5).state(), canopen::NmtState::stopped);
  EXPECT_EQ(rig.node(6).state(), canopen::NmtState::stopped);
  EXPECT_EQ(rig.written,
            (std::vector<Frame>{Frame::standard(0, {0x01, 5}), Frame::standard(0, {0x02, 0})}));
  rig.request(nmt_request(3, 5, 0x55));  // not a CiA 301 command
  ASSERT_NE(rig.result(3), nullptr);
  EXPECT_EQ(rig.result(3)->abort_code(), 0x05040001u);
  EXPECT_EQ(rig.written.size(), 2u);
}

TEST(GatewayRemote, SetNodeIdIsAnsweredByTheBootUpOfTheNewId) {
  Rig rig({node_spec(7, sim::NodeKind::fpga)});
  rig.request(nmt_request(1, 7, 0xE0, 9));
  EXPECT_EQ(rig.written.front(), Frame::standard(0, {0xE0, 7, 9}));
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0u) << rig.result(1)->detail();
  EXPECT_EQ(rig.node(9).id(), 9);
  // Local 9 is not mapped: the node's pair moved with it and it keeps surface id 17, which the
  // answer names.
  EXPECT_EQ(rig.result(1)->data(), std::string(1, '\x11'));
  EXPECT_EQ(rig.map.surface_of(0, 9), 17);
  // A node that is not there: no boot-up, answered once when the table gives up.
  rig.request(nmt_request(2, 3, 0xE0, 4));
  EXPECT_EQ(rig.result(2), nullptr);
  rig.advance(10s);
  ASSERT_NE(rig.result(2), nullptr);
  EXPECT_EQ(rig.result(2)->abort_code(), 0x05040000u);
  EXPECT_EQ(rig.result(2)->detail(), "no boot-up on new id");
  rig.advance(10s);
  EXPECT_EQ(rig.results.size(), 2u);
}

TEST(GatewayRemote, NodesQueryListsTheTableWithHeartbeatAgeAndLastEmcy) {
  Rig rig({node_spec(5), node_spec(6)});
  rig.advance(1500ms);
  rig.from_node(Frame::standard(0x085, {0x10, 0x82, 0x11, 0, 0, 0, 0, 0}));
  // Device types learnt from answers someone else read (a master at boot): 1000h:00 only.
  rig.from_node(Frame::standard(0x585, {0x43, 0x00, 0x10, 0x00, 0x91, 0x01, 0x00, 0x00}));
  rig.from_node(Frame::standard(0x586, {0x43, 0x01, 0x10, 0x00, 0x91, 0x01, 0x00, 0x00}));
  rig.from_node(Frame::standard(0x586, {0x41, 0x00, 0x10, 0x00, 0x04, 0x00, 0x00, 0x00}));
  rig.advance(200ms);
  v1::RemoteRequest r;
  r.set_request_id(1);
  r.mutable_nodes();
  rig.request(r);
  ASSERT_NE(rig.result(1), nullptr);
  const v1::RemoteResult& result = *rig.result(1);
  EXPECT_EQ(result.abort_code(), 0u);
  ASSERT_EQ(result.nodes_size(), 2);
  const v1::NodeRow& five = result.nodes(0);
  EXPECT_EQ(five.module_id(), 1u);
  EXPECT_EQ(five.local_node(), 5u);
  EXPECT_EQ(five.surface_node(), 15u);
  EXPECT_EQ(five.profile(), "cia301");
  EXPECT_EQ(five.nmt_state(), 0x7Fu);
  EXPECT_EQ(five.boot_count(), 1u);
  // The simulated nodes here send no heartbeat (1017h = 0): alive, no heartbeat age to show.
  EXPECT_EQ(five.heartbeat_age_ms(), -1);
  EXPECT_FALSE(five.lost());
  EXPECT_EQ(five.last_emcy_code(), 0x8210u);
  EXPECT_EQ(five.last_emcy_register(), 0x11u);
  EXPECT_EQ(five.last_emcy_age_ms(), 200);
  EXPECT_EQ(five.kind(), "CiA401");
  EXPECT_EQ(result.nodes(1).local_node(), 6u);
  EXPECT_EQ(result.nodes(1).last_emcy_age_ms(), -1);
  EXPECT_EQ(result.nodes(1).kind(), "");  // 1001h and a segmented answer say nothing of it
  // A manufacturer profile (seed 003: profile 0, the version in the high word).
  rig.from_node(Frame::standard(0x586, {0x43, 0x00, 0x10, 0x00, 0x00, 0x00, 0x03, 0x00}));
  r.set_request_id(2);
  rig.request(r);
  ASSERT_NE(rig.result(2), nullptr);
  EXPECT_EQ(rig.result(2)->nodes(1).kind(), "mfr-v3");
}

TEST(GatewayRemote, ARepeatedRequestIdIsNeverRunTwice) {
  Rig rig({node_spec(5)});
  rig.request(sdo_request(1, 5, false, kDomain, "a"), false);
  rig.request(sdo_request(1, 5, false, kDomain, "b"), false);  // while it is queued
  rig.run();
  rig.request(sdo_request(1, 5, false, kDomain, "c"));  // after it finished
  EXPECT_EQ(rig.results.size(), 1u);
  EXPECT_EQ(rig.core->counters().duplicates, 2u);
  rig.request(sdo_request(2, 5, true, kDomain));
  EXPECT_EQ(rig.result(2)->data(), "a");
}

TEST(GatewayRemote, LssOnAModuleWithoutItIsRefused) {
  Rig rig({node_spec(5)});
  v1::RemoteRequest r;
  r.set_request_id(1);
  r.set_module_id(1);
  r.mutable_lss()->set_command("lss_get_node");
  rig.request(r);
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0x08000020u);
  EXPECT_TRUE(rig.result(1)->not_supported());  // the endpoint says ERROR:100, not an abort
  EXPECT_TRUE(rig.written.empty());
}

v1::RemoteRequest lss_request(std::uint64_t id, std::string command,
                              std::vector<std::uint32_t> args) {
  v1::RemoteRequest r;
  r.set_request_id(id);
  r.set_module_id(1);
  r.mutable_lss()->set_command(std::move(command));
  for (auto a : args) r.mutable_lss()->add_args(a);
  return r;
}

TEST(GatewayRemote, LssOnTheLssModuleRunsTheServiceAndKeepsItsAnswersOffTheSurface) {
  sim::NodeSpec spec = node_spec(5);
  spec.identity = {0x1A2, 0x1234, 0x10002, 0xCAFEF00D};
  Rig rig({spec}, {}, IdProfile::cia301, true);
  rig.request(lss_request(1, "lss_switch_glob", {1}));
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0u) << rig.result(1)->detail();
  rig.request(lss_request(2, "lss_get_node", {}));
  ASSERT_NE(rig.result(2), nullptr);
  EXPECT_EQ(rig.result(2)->abort_code(), 0u) << rig.result(2)->detail();
  EXPECT_EQ(rig.result(2)->data(), std::string("\x05\0\0\0", 4));
  rig.request(lss_request(3, "lss_inquire_addr", {3}));
  ASSERT_NE(rig.result(3), nullptr);
  EXPECT_EQ(rig.result(3)->data(), std::string("\x0D\xF0\xFE\xCA", 4));
  for (const Frame& f : rig.surface) EXPECT_NE(f.id, 0x7E4u);
  rig.request(lss_request(4, "lss_set_node", {300}));  // out of range: refused before the bus
  ASSERT_NE(rig.result(4), nullptr);
  EXPECT_EQ(rig.result(4)->abort_code(), 0x05040001u);
}

TEST(GatewayRemote, FlashRunsTheLoaderSequenceWithProgressAndOneResult) {
  sim::NodeSpec qd = node_spec(4, sim::NodeKind::qd);
  Rig rig({qd}, {}, IdProfile::qd);
  rig.advance(10ms);
  std::vector<std::uint8_t> application(3000);
  for (std::size_t i = 0; i < application.size(); ++i)
    application[i] = static_cast<std::uint8_t>(i);
  const std::vector<std::uint8_t> image = sim::firmware::make_image(application);
  v1::RemoteRequest r;
  r.set_request_id(1);
  r.set_module_id(1);
  r.set_local_node(4);
  r.mutable_flash()->set_image(std::string(image.begin(), image.end()));
  rig.request(r, false);
  // The first step is reported at once (progress is dropped once the result is queued: the
  // simulated loader answers without delay, so the later steps finish within one run()).
  std::vector<v1::RemoteProgress> progress = rig.core->take_progress();
  ASSERT_EQ(progress.size(), 1u);
  EXPECT_EQ(progress[0].request_id(), 1u);
  EXPECT_EQ(progress[0].step(), "stop");
  EXPECT_EQ(progress[0].bytes_total(), image.size());
  rig.run();
  for (int i = 0; i < 100 && rig.results.empty(); ++i) {
    rig.advance(50ms);
    for (auto& p : rig.core->take_progress()) progress.push_back(p);
  }
  ASSERT_NE(rig.result(1), nullptr);
  EXPECT_EQ(rig.result(1)->abort_code(), 0u) << rig.result(1)->detail();
  EXPECT_EQ(rig.node(4).counters().images_accepted, 1u);
  EXPECT_FALSE(rig.node(4).in_loader());
  for (const Frame& f : rig.surface) EXPECT_FALSE(is_sdo_response_of(f, 4)) << f.id;
  EXPECT_EQ(rig.core->pending(), 0u);
}

TEST(GatewayRemote, ACorruptImageFailsNamingTheStepAndLeavesTheNodeInItsLoader) {
  Rig rig({node_spec(4, sim::NodeKind::qd)}, {}, IdProfile::qd);
  std::vector<std::uint8_t> image = sim::firmware::make_image(std::vector<std::uint8_t>(600, 0x5A));
  image[10] ^= 0xFF;  // the CRC-32 trailer no longer matches
  v1::RemoteRequest r;
  r.set_request_id(7);
  r.set_module_id(1);
  r.set_local_node(4);
  r.mutable_flash()->set_image(std::string(image.begin(), image.end()));
  rig.request(r);
  for (int i = 0; i < 100 && rig.results.empty(); ++i) rig.advance(100ms);
  ASSERT_NE(rig.result(7), nullptr);
  EXPECT_NE(rig.result(7)->abort_code(), 0u);
  EXPECT_NE(rig.result(7)->detail().find(':'), std::string::npos) << rig.result(7)->detail();
  EXPECT_TRUE(rig.node(4).in_loader());
  EXPECT_EQ(rig.results.size(), 1u);
}

// Issue 28, the loader census: of the ids asked, the node in its loader is found, the one
// running its application (it has no 1F57h) and the absent one are not; nothing of it reaches the
// surface or the results.
TEST(GatewayRemote, TheLoaderProbeFindsTheNodeInItsLoaderOnly) {
  sim::NodeSpec stuck = node_spec(4, sim::NodeKind::qd);
  stuck.loader.application_valid = false;  // stays in its loader from power-on
  Rig rig({stuck, node_spec(5, sim::NodeKind::qd)}, {}, IdProfile::qd);
  rig.advance(10ms);
  ASSERT_TRUE(rig.node(4).in_loader());
  ASSERT_FALSE(rig.node(5).in_loader());
  rig.core->ask_silent_nodes(0, {4, 5, 6}, GatewayRemote::CensusQuestion::in_loader, 200ms,
                             rig.now);
  rig.run();
  for (int i = 0; i < 5; ++i) rig.advance(100ms);  // node 6 never answers
  const auto found = rig.core->take_found_in_loader();
  ASSERT_EQ(found.size(), 1u);
  EXPECT_EQ(found[0].module_index, 0u);
  EXPECT_EQ(found[0].local, 4);
  EXPECT_TRUE(rig.core->take_found_in_loader().empty());  // taken once
  EXPECT_TRUE(rig.results.empty());
  EXPECT_EQ(rig.core->counters().census_questions, 3u);
  EXPECT_EQ(rig.core->counters().requests, 0u);  // the surface asked nothing
  for (const Frame& f : rig.surface) {
    EXPECT_FALSE(is_sdo_response_of(f, 4) || is_sdo_response_of(f, 5)) << f.id;
  }
  EXPECT_EQ(rig.core->pending(), 0u);
}

// The census's ids are the gateway's own (top bit set). A surface request that carries one, even
// the id of a probe still running, gets its own answer (refused) instead of being taken for the
// probe and kept here; and the probe still finds its loader.
TEST(GatewayRemote, ARequestIdOfTheCensusFromTheSurfaceIsRefusedNotSwallowed) {
  sim::NodeSpec stuck = node_spec(4, sim::NodeKind::qd);
  stuck.loader.application_valid = false;
  Rig rig({stuck}, {}, IdProfile::qd);
  rig.advance(10ms);
  rig.core->ask_silent_nodes(0, {4}, GatewayRemote::CensusQuestion::in_loader, 200ms,
                             rig.now);  // its id: 2^63 + 1
  constexpr std::uint64_t kFirstProbeId = (std::uint64_t{1} << 63) | 1;
  v1::RemoteRequest read = sdo_request(kFirstProbeId, 4, true, 0x1000);
  rig.request(read);
  ASSERT_NE(rig.result(kFirstProbeId), nullptr);
  EXPECT_NE(rig.result(kFirstProbeId)->abort_code(), 0u);
  EXPECT_NE(rig.result(kFirstProbeId)->detail().find("reserved"), std::string::npos);
  rig.request(read);  // again: answered again, never taken for a duplicate
  EXPECT_EQ(rig.results.size(), 2u);
  for (int i = 0; i < 5; ++i) rig.advance(100ms);
  const auto found = rig.core->take_found_in_loader();
  ASSERT_EQ(found.size(), 1u);
  EXPECT_EQ(found[0].local, 4);
  EXPECT_EQ(rig.core->counters().requests, 2u);
  EXPECT_EQ(rig.core->counters().census_questions, 1u);
}

// Issue 28: the census only asks. A surface master's request to a node under a census question
// (an absent one here, which never answers) must not meet a collision abort (0x08000021) that a
// scanning master would take for a node: the question ends at once, unanswered, with nothing
// written (an abort frame would end the master's own transfer at the node). A surface request's
// transfer never gives way.
TEST(GatewayRemote, ACensusQuestionGivesWayToASurfaceMaster) {
  Rig rig({node_spec(4)});
  rig.advance(10ms);
  rig.core->ask_silent_nodes(0, {6}, GatewayRemote::CensusQuestion::present, 200ms, rig.now);
  rig.run();
  ASSERT_TRUE(rig.core->transferring(0, 6));
  const std::size_t written = rig.written.size();
  EXPECT_TRUE(rig.core->yield_census(0, 6));
  EXPECT_FALSE(rig.core->transferring(0, 6));
  EXPECT_EQ(rig.core->pending(), 0u);
  EXPECT_EQ(rig.core->counters().census_yielded, 1u);
  for (int i = 0; i < 5; ++i) rig.advance(100ms);
  EXPECT_EQ(rig.written.size(), written);  // no abort, no retry
  EXPECT_TRUE(rig.results.empty());
  EXPECT_TRUE(rig.core->take_found_in_loader().empty());
  EXPECT_FALSE(rig.core->yield_census(0, 6));  // nothing running
  rig.request(sdo_request(7, 4, true, 0x1000), false);
  ASSERT_TRUE(rig.core->transferring(0, 4));
  EXPECT_FALSE(rig.core->yield_census(0, 4));
  EXPECT_TRUE(rig.core->transferring(0, 4));
}

// The rule for a surface master's frame to a node the gateway runs a transfer with, on its own:
// a census question gives way and the frame passes; a surface request's transfer refuses it
// with the node's abort 0x08000021 naming the master's object; the master's own abort is refused
// with nothing to answer; anything else passes.
TEST(GatewayRemote, AMastersRequestMeetingTheGatewaysTransferIsRefusedUnlessTheCensusAsks) {
  Rig rig({node_spec(4)});
  rig.advance(10ms);
  const Frame read_2003 = Frame::standard(0x604, {0x40, 0x03, 0x20, 0x01, 0, 0, 0, 0});
  EXPECT_FALSE(rig.core->on_master_frame(0, read_2003).refused);  // nothing running

  rig.core->ask_silent_nodes(0, {4}, GatewayRemote::CensusQuestion::present, 200ms, rig.now);
  ASSERT_TRUE(rig.core->transferring(0, 4));
  EXPECT_FALSE(rig.core->on_master_frame(0, read_2003).refused);
  EXPECT_FALSE(rig.core->transferring(0, 4));
  EXPECT_EQ(rig.core->counters().census_yielded, 1u);

  rig.request(sdo_request(7, 4, true, 0x1000), false);
  ASSERT_TRUE(rig.core->transferring(0, 4));
  const GatewayRemote::MasterCollision refused = rig.core->on_master_frame(0, read_2003);
  EXPECT_TRUE(refused.refused);
  ASSERT_TRUE(refused.abort.has_value());
  EXPECT_EQ(*refused.abort, Frame::standard(0x584, {0x80, 0x03, 0x20, 0x01, 0x21, 0, 0, 0x08}));
  const Frame masters_abort = Frame::standard(0x604, {0x80, 0x03, 0x20, 0x01, 0, 0, 0, 0x05});
  EXPECT_TRUE(rig.core->on_master_frame(0, masters_abort).refused);
  EXPECT_FALSE(rig.core->on_master_frame(0, masters_abort).abort.has_value());
  EXPECT_FALSE(rig.core->on_master_frame(0, Frame::standard(0x204, {1})).refused);     // RPDO1
  EXPECT_FALSE(rig.core->on_master_frame(0, Frame::standard(0x604, {0x40})).refused);  // short
  EXPECT_TRUE(rig.core->transferring(0, 4));  // the request's transfer never gives way
}

// The question was already on the bus when it gave way: the node's answer to it is the census's,
// taken here, so that the master gets only the answer to its own request. An answer naming
// another object (the master's) passes, and so does one after the question's own deadline.
TEST(GatewayRemote, AnAnswerToACensusQuestionThatGaveWayNeverReachesTheMaster) {
  Rig rig({node_spec(4)});
  rig.advance(10ms);
  rig.core->ask_silent_nodes(0, {4}, GatewayRemote::CensusQuestion::present, 200ms, rig.now);
  std::vector<Frame> question;  // written, not yet on the bus: the master's request meets it
  for (auto& b : rig.core->bus_frames())
    question.insert(question.end(), b.frames.begin(), b.frames.end());
  rig.core->bus_frames().clear();
  ASSERT_EQ(question.size(), 1u);
  ASSERT_TRUE(rig.core->yield_census(0, 4));
  rig.to_bus(question[0]);  // node 4 answers 1000h:00
  EXPECT_EQ(rig.core->counters().census_late_answers, 1u);
  for (const Frame& f : rig.surface) EXPECT_FALSE(is_sdo_response_of(f, 4)) << f.id;
  // The master's own answer (another object) passes.
  const Frame masters = Frame::standard(0x584, {0x43, 0x03, 0x20, 0x00, 1, 2, 3, 4});
  EXPECT_FALSE(rig.core->on_bus_frame(0, masters, rig.now));
  // Once taken, or after the question's deadline, a 1000h:00 answer is the master's.
  const Frame device_type = Frame::standard(0x584, {0x43, 0x00, 0x10, 0x00, 0x91, 0x01, 0, 0});
  EXPECT_FALSE(rig.core->on_bus_frame(0, device_type, rig.now));
  rig.core->ask_silent_nodes(0, {4}, GatewayRemote::CensusQuestion::present, 200ms, rig.now);
  rig.core->bus_frames().clear();
  ASSERT_TRUE(rig.core->yield_census(0, 4));
  EXPECT_FALSE(rig.core->on_bus_frame(0, device_type, rig.now + 200ms));
  EXPECT_EQ(rig.core->counters().census_late_answers, 1u);
}

// The census asks exactly the silent mapped ids: those the node table has heard, the unmapped
// ones and modules with the census off are not asked; a qd module asks 1F57h:01 (its loaders),
// any other 1000h:00.
TEST(GatewayRemote, TheCensusAsksEachSilentMappedIdItsProfilesQuestion) {
  NodeMap map;
  ASSERT_TRUE(map.add_module(1, {{1, 11}, {2, 12}, {3, 13}}, IdProfile::cia301).empty());
  ASSERT_TRUE(map.add_module(2, {{4, 24}}, IdProfile::qd).empty());
  ASSERT_TRUE(map.add_module(3, {{5, 35}}, IdProfile::cia301).empty());
  NodeTable table;
  table.add_module(IdProfile::cia301);
  table.add_module(IdProfile::qd);
  table.add_module(IdProfile::cia301);
  std::vector<NodeEvent> events;
  table.on_bus_frame(0, Frame::standard(0x702, {0x05}), t0, events);  // node 2 beats
  ASSERT_NE(table.node(0, 2), nullptr);
  GatewayRemote core(map, table, {{1, false, true}, {2, false, true}, {3, false, false}}, {},
                     [](std::size_t, NodeId) { return false; });
  const auto asked = core.census(200ms, t0);
  ASSERT_EQ(asked.size(), 2u);
  EXPECT_EQ(asked[0].module_index, 0u);
  EXPECT_EQ(asked[0].ids, 2u);  // 1 and 3
  EXPECT_EQ(asked[0].question, GatewayRemote::CensusQuestion::present);
  EXPECT_EQ(asked[1].module_index, 1u);
  EXPECT_EQ(asked[1].ids, 1u);
  EXPECT_EQ(asked[1].question, GatewayRemote::CensusQuestion::in_loader);
  std::set<std::pair<std::size_t, std::uint32_t>> requests;
  for (const auto& b : core.bus_frames()) {
    for (const Frame& f : b.frames) {
      requests.insert({b.module_index, f.id});
      const std::uint16_t index = static_cast<std::uint16_t>(f.data[1] | (f.data[2] << 8));
      EXPECT_EQ(f.data[0], 0x40) << f.id;  // an upload request
      EXPECT_EQ(index, b.module_index == 1 ? 0x1F57 : 0x1000) << f.id;
      EXPECT_EQ(f.data[3], b.module_index == 1 ? 1 : 0) << f.id;
    }
  }
  const std::set<std::pair<std::size_t, std::uint32_t>> expected{
      {0, 0x601}, {0, 0x603}, {1, 0x604}};
  EXPECT_EQ(requests, expected);
  EXPECT_EQ(core.counters().census_questions, 3u);
  EXPECT_EQ(core.counters().requests, 0u);
}

// produce(): results go reliable and in order, and wait while the session has no room for them;
// progress goes unreliable, after them, the latest of each request only.
TEST(GatewayRemote, ProduceSendsResultsReliablyAndWaitsForRoom) {
  Rig rig({node_spec(5)});
  rig.core->on_request(sdo_request(1, 5, true, 0x1000), rig.now);
  rig.core->on_request(sdo_request(2, 5, true, 0x1000), rig.now);
  for (int round = 0; round < 10; ++round) {  // the bus only: Rig::run() would take the results
    std::vector<Frame> out;
    for (auto& b : rig.core->bus_frames()) out.insert(out.end(), b.frames.begin(), b.frames.end());
    rig.core->bus_frames().clear();
    for (const Frame& f : out) rig.to_bus(f);
  }
  ASSERT_TRUE(rig.core->has_results());
  test::FakeSink sink;
  sink.reliable_room_ = false;
  rig.core->produce(sink);
  EXPECT_TRUE(sink.sent.empty());
  EXPECT_TRUE(rig.core->has_results());
  sink.reliable_room_ = true;
  rig.core->produce(sink);
  ASSERT_EQ(sink.sent.size(), 2u);
  std::vector<std::uint64_t> ids;
  for (const auto& sent : sink.sent) {
    EXPECT_TRUE(sent.reliable);
    v1::Payload p;
    ASSERT_TRUE(p.ParseFromString(sent.bytes));
    ASSERT_TRUE(p.has_remote_result());
    EXPECT_EQ(p.remote_result().abort_code(), 0u);
    ids.push_back(p.remote_result().request_id());
  }
  EXPECT_EQ(ids, (std::vector<std::uint64_t>{1, 2}));
  EXPECT_FALSE(rig.core->has_results());
  EXPECT_EQ(sink.reliable_calls_while_full_, 0u);
}

// The Gateway class itself: a simulated node on a virtual module bus, and a scripted surface end
// (its own PeerStream over an in-memory link) that sends RemoteRequest payloads and frames.
class GatewayWithScriptedSurface : public ::testing::Test {
 protected:
  static constexpr NodeId kLocal = 5, kSurface = 15;

  void SetUp() override {
    NodeMap map;
    ASSERT_TRUE(map.add_module(1, {{kLocal, kSurface}}).empty());
    std::vector<GatewayModule> modules;
    GatewayModule m;
    m.id = 1;
    m.bus = module_bus.connect("gateway");
    modules.push_back(std::move(m));
    gateway =
        std::make_unique<Gateway>(io.get_executor(), "gw", std::move(map), std::move(modules));
    node_bus.on_frames = [this] {
      for (; node_seen < node_bus.frames.size(); ++node_seen) {
        for (const Frame& reply : node.on_frame(node_bus.frames[node_seen], Clock::now())) {
          if (hold_replies) {
            held.push_back(reply);
          } else {
            node_bus.send(reply);
          }
        }
      }
    };
    gateway->start();
    backbone::SessionIdentity identity;
    identity.role = v1::Hello::ROLE_SURFACE;
    identity.expected_peer = v1::Hello::ROLE_GATEWAY;
    identity.name = "scripted-surface";
    identity.session_id = backbone::random_session_id();
    backbone::MemoryLinkOptions options;
    options.name = "backbone";
    auto pair = backbone::make_memory_link_pair(io.get_executor(), options);
    gateway->attach(pair.a);
    session = backbone::SessionLink::create(pair.b, identity, tuning.session, &stream, nullptr,
                                            session_counters);
    session->start();
    ASSERT_TRUE(test::run_until(io, [&] { return gateway->connected() && stream.up(); }));
    for (const Frame& f : node.boot(Clock::now())) node_bus.send(f);
    // The node's boot-up crosses to the surface: frames do reach it.
    ASSERT_TRUE(test::run_until(io, [&] { return saw_on_surface(0x700 + kSurface); }));
  }
  void TearDown() override {
    session->close();
    gateway->stop();
    node_bus.close();
    EXPECT_TRUE(test::run_until(io, [&] { return node_bus.done(); }));
  }

  void send(const v1::Payload& payload) {
    outgoing.push_back(payload.SerializeAsString());
    stream.wake();
  }
  void send_frame(const Frame& f) {
    v1::Payload p;
    FrameBatchBuilder b;
    b.start(*p.mutable_frames(), kAnyModule);
    b.append(*p.mutable_frames(), f);
    send(p);
  }
  void on_payload(std::span<const std::uint8_t> bytes) {
    v1::Payload p;
    ASSERT_TRUE(p.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())));
    if (p.has_remote_result()) results.push_back(p.remote_result());
    if (p.has_frames()) {
      std::vector<Frame> frames;
      ASSERT_EQ(decode_frame_batch(p.frames(), frames), BatchError::none);
      surface_frames.insert(surface_frames.end(), frames.begin(), frames.end());
    }
  }
  bool saw_on_surface(std::uint32_t id) const {
    return std::any_of(surface_frames.begin(), surface_frames.end(),
                       [id](const Frame& f) { return f.id == id; });
  }

  using Clock = std::chrono::steady_clock;
  boost::asio::io_context io{1};
  can::VirtualBus module_bus{io.get_executor(), "module-bus"};
  test::BusRecorder node_bus{io, module_bus.connect("node")};
  static sim::NodeSpec spec_with_value() {
    sim::NodeSpec spec = node_spec(kLocal);
    const std::string value = pattern(20);
    spec.objects[0].value.assign(value.begin(), value.end());
    return spec;
  }
  sim::SimNode node{spec_with_value()};
  std::size_t node_seen = 0;
  bool hold_replies = false;
  std::vector<Frame> held;
  std::unique_ptr<Gateway> gateway;
  BackboneTuning tuning;
  backbone::SessionCounters session_counters;
  std::deque<std::string> outgoing;
  std::vector<v1::RemoteResult> results;
  std::vector<Frame> surface_frames;
  backbone::PeerStream stream{
      tuning.session,
      {[this](backbone::PayloadSink& sink) {
         while (!outgoing.empty() && sink.reliable_room(outgoing.front().size())) {
           sink.send_reliable(std::move(outgoing.front()));
           outgoing.pop_front();
         }
       },
       [this](std::span<const std::uint8_t> payload, bool) { on_payload(payload); },
       [](const v1::Hello&) {}, [] {}}};
  std::shared_ptr<backbone::SessionLink> session;
};

TEST_F(GatewayWithScriptedSurface, ARequestGetsOneResultAndItsSdoFramesNeverReachTheSurface) {
  // A segmented read (20 bytes) holds the node's answers back, so
  // the surface master's request to the same node arrives while the gateway's transfer runs.
  hold_replies = true;
  v1::Payload request;
  *request.mutable_remote_request() = sdo_request(41, kLocal, true, kDomain);
  send(request);
  ASSERT_TRUE(test::run_until(io, [&] { return !held.empty(); }));
  send_frame(Frame::standard(0x600 + kSurface, {0x40, 0x00, 0x20, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(test::run_until(io, [&] { return saw_on_surface(0x580 + kSurface); }));
  const auto refusal = std::find_if(surface_frames.begin(), surface_frames.end(),
                                    [](const Frame& f) { return f.id == 0x580 + kSurface; });
  EXPECT_EQ(*refusal,
            Frame::standard(0x580 + kSurface, {0x80, 0x00, 0x20, 0, 0x21, 0x00, 0x00, 0x08}));
  EXPECT_EQ(gateway->counters().sdo_collisions, 1u);
  EXPECT_EQ(node_bus.count(0x600 + kLocal), 1u);  // the master's request never reached the node
  // The node answers now: the gateway's transfer completes.
  hold_replies = false;
  for (const Frame& f : held) node_bus.send(f);
  held.clear();
  ASSERT_TRUE(test::run_until(io, [&] { return !results.empty(); }));
  ASSERT_EQ(results.size(), 1u);
  EXPECT_EQ(results[0].request_id(), 41u);
  EXPECT_EQ(results[0].abort_code(), 0u) << results[0].detail();
  EXPECT_EQ(results[0].data(), pattern(20));  // segmented
  // A second request after it, and a repeat of the first: one more result, none for the repeat.
  send(request);
  *request.mutable_remote_request() = sdo_request(42, kLocal, true, 0x1000);
  send(request);
  ASSERT_TRUE(test::run_until(io, [&] { return results.size() >= 2; }));
  EXPECT_EQ(results[1].request_id(), 42u);
  EXPECT_EQ(results[1].data().size(), 4u);
  // Then a master's read passes through as always (the gateway's transfers are done): its
  // answer, queued behind anything the node's earlier responses could have left in the outbox,
  // is the only SDO response besides the refusal that ever reached the surface.
  const std::size_t before = surface_frames.size();
  send_frame(Frame::standard(0x600 + kSurface, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(test::run_until(io, [&] {
    return surface_frames.size() > before && surface_frames.back().id == 0x580 + kSurface;
  }));
  EXPECT_EQ(std::count_if(surface_frames.begin(), surface_frames.end(),
                          [](const Frame& f) { return f.id == 0x580 + kSurface; }),
            2);
  EXPECT_EQ(surface_frames.back().data[0], 0x43);  // the node's expedited answer to the master
  EXPECT_EQ(results.size(), 2u);
  const GatewayCounters c = gateway->counters();
  EXPECT_EQ(c.remote.requests, 2u);
  EXPECT_EQ(c.remote.duplicates, 1u);
  EXPECT_EQ(c.remote.failed, 0u);
}

}  // namespace
}  // namespace canbridge::bridge
