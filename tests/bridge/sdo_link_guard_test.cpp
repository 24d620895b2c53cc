// The surface's answer for nodes behind a lost link: abort 0x05040000 at once, never silence.
#include "bridge/sdo_link_guard.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

const can::Frame kHeartbeat34 = can::Frame::standard(0x722, {0x05});  // node 34: gateway 1
const can::Frame kHeartbeat70 = can::Frame::standard(0x746, {0x05});  // node 70: gateway 2
const can::Frame kRead1018 = can::Frame::standard(0x622, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0});

can::Frame abort_of(std::uint32_t cob, std::uint16_t index, std::uint8_t sub) {
  return can::Frame::standard(
      cob, {0x80, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
            0x00, 0x00, 0x04, 0x05});
}

TEST(SdoLinkGuard, ANodeWhoseGatewayIsDownIsAnsweredWithAnAbortAtOnce) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  bool up = false;
  const auto verdict = guard.on_surface_frame(kRead1018, [&](auto g) { return g == 1 && up; });
  EXPECT_FALSE(verdict.forward);
  ASSERT_TRUE(verdict.reply);
  EXPECT_EQ(*verdict.reply, abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_EQ(guard.counters().aborted_at_once, 1u);
  up = true;  // the link returns: requests flow again
  const auto again = guard.on_surface_frame(kRead1018, [&](auto) { return up; });
  EXPECT_TRUE(again.forward);
  EXPECT_FALSE(again.reply);
}

TEST(SdoLinkGuard, RequestsInFlightWhenTheLinkDropsAreAbortedOnlyForThatGateway) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  (void)guard.on_gateway_frame(2, kHeartbeat70);
  auto all_up = [](auto) { return true; };
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, all_up).forward);
  const can::Frame write_1017 =
      can::Frame::standard(0x646, {0x2B, 0x17, 0x10, 0x00, 0xC8, 0x00, 0, 0});
  EXPECT_TRUE(guard.on_surface_frame(write_1017, all_up).forward);
  const auto aborts = guard.on_gateway_down(1);
  ASSERT_EQ(aborts.size(), 1u);
  EXPECT_EQ(aborts[0], abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_EQ(guard.counters().aborted_in_flight, 1u);
  EXPECT_TRUE(guard.on_gateway_down(1).empty());  // once
  const auto other = guard.on_gateway_down(2);
  ASSERT_EQ(other.size(), 1u);
  EXPECT_EQ(other[0], abort_of(0x5C6, 0x1017, 0x00));
}

TEST(SdoLinkGuard, AnsweredTransfersAndMasterAbortsAreNotInFlight) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  auto up = [](auto) { return true; };
  guard.on_surface_frame(kRead1018, up);
  (void)guard.on_gateway_frame(1,
                               can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4}));
  EXPECT_TRUE(guard.on_gateway_down(1).empty());
  guard.on_surface_frame(kRead1018, up);
  guard.on_surface_frame(can::Frame::standard(0x622, {0x80, 0x18, 0x10, 0x01, 0, 0, 4, 5}), up);
  EXPECT_TRUE(guard.on_gateway_down(1).empty());
}

TEST(SdoLinkGuard, SegmentsAbortWithTheObjectOfTheirTransfer) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  auto up = [](auto) { return true; };
  guard.on_surface_frame(can::Frame::standard(0x622, {0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0}), up);
  (void)guard.on_gateway_frame(1,
                               can::Frame::standard(0x5A2, {0x41, 0x08, 0x10, 0x00, 33, 0, 0, 0}));
  guard.on_surface_frame(can::Frame::standard(0x622, {0x60, 0, 0, 0, 0, 0, 0, 0}), up);  // segment
  const auto aborts = guard.on_gateway_down(1);
  ASSERT_EQ(aborts.size(), 1u);
  EXPECT_EQ(aborts[0], abort_of(0x5A2, 0x1008, 0x00));
}

TEST(SdoLinkGuard, ALateAnswerToAnAbortedRequestNeverReachesTheMaster) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  auto up = [](auto) { return true; };
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, up).forward);
  ASSERT_EQ(guard.on_gateway_down(1).size(), 1u);  // the master sees 0x05040000
  // The request had reached the node; its answer crosses once the link is back: dropped.
  const can::Frame late = can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4});
  EXPECT_FALSE(guard.on_gateway_frame(1, late));
  EXPECT_EQ(guard.counters().late_responses_dropped, 1u);
  EXPECT_TRUE(guard.on_gateway_frame(1, kHeartbeat34));  // other frames of the node pass
  // A new request: its answer is the master's again.
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, up).forward);
  EXPECT_TRUE(guard.on_gateway_frame(1, late));
  // Aborted at once (link known down), then the link returns: same rule.
  bool link = false;
  EXPECT_FALSE(guard.on_surface_frame(kRead1018, [&](auto) { return link; }).forward);
  link = true;
  EXPECT_FALSE(guard.on_gateway_frame(1, late));
  EXPECT_EQ(guard.counters().late_responses_dropped, 2u);
}

// Issue 27, "a late abort": a master's upload to an absent node stayed pending and was aborted
// 56 s later, when the link dropped, reaching a master that had long since moved on.
TEST(SdoLinkGuard, NoAbortComesLaterThanTheTransferCouldStillBeOpen) {
  SdoLinkGuard guard({.transfer_open_for = std::chrono::milliseconds(4000)});
  const SdoLinkGuard::Clock::time_point t0{std::chrono::hours(1)};
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  (void)guard.on_gateway_frame(1, kHeartbeat70);
  auto up = [](auto) { return true; };
  ASSERT_TRUE(guard.on_surface_frame(kRead1018, up, t0).forward);  // node 34 never answers
  const can::Frame read_70 = can::Frame::standard(0x646, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  ASSERT_TRUE(guard.on_surface_frame(read_70, up, t0 + std::chrono::seconds(53)).forward);
  // The link drops 56 s after the first request, 3 s after the second: only the second's
  // master can still be waiting.
  const auto aborts = guard.on_gateway_down(1, t0 + std::chrono::seconds(56));
  ASSERT_EQ(aborts.size(), 1u);
  EXPECT_EQ(aborts[0], abort_of(0x5C6, 0x1000, 0x00));
  EXPECT_EQ(guard.counters().aborted_in_flight, 1u);
  EXPECT_EQ(guard.counters().stale_aborts_dropped, 1u);
  // Its answer, should it come after all, is as late as the abort would have been.
  EXPECT_FALSE(
      guard.on_gateway_frame(1, can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4})));
  // The same bound for a request the backbone gave up.
  ASSERT_TRUE(guard.on_surface_frame(kRead1018, up, t0 + std::chrono::seconds(60)).forward);
  EXPECT_FALSE(guard.on_request_discarded(kRead1018, t0 + std::chrono::seconds(65)));
  EXPECT_EQ(guard.counters().stale_aborts_dropped, 2u);
  ASSERT_TRUE(guard.on_surface_frame(kRead1018, up, t0 + std::chrono::seconds(70)).forward);
  EXPECT_TRUE(guard.on_request_discarded(kRead1018, t0 + std::chrono::seconds(74)));
}

// Issue 27: every request withdrawn at a cut is accounted for by how its master gets its answer,
// so that the counters prove none was withdrawn without one.
TEST(SdoLinkGuard, EveryWithdrawnRequestIsAccountedForOnce) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  (void)guard.on_gateway_frame(1, kHeartbeat70);
  auto up = [](auto) { return true; };
  // Node 34: the master gave up on one request (its own timeout) and sent another; both queued.
  const can::Frame given_up = can::Frame::standard(0x622, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  ASSERT_TRUE(guard.on_surface_frame(given_up, up).forward);
  ASSERT_TRUE(guard.on_surface_frame(kRead1018, up).forward);
  // Node 70: its request was answered, yet still unacknowledged when the link dropped.
  const can::Frame read_70 = can::Frame::standard(0x646, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  ASSERT_TRUE(guard.on_surface_frame(read_70, up).forward);
  ASSERT_TRUE(
      guard.on_gateway_frame(1, can::Frame::standard(0x5C6, {0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4})));
  // Node 90: no gateway claims it, so the guard does not follow it.
  const can::Frame read_90 = can::Frame::standard(0x65A, {0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0});
  for (const can::Frame& f : {given_up, kRead1018, read_70, read_90}) guard.on_request_withdrawn(f);
  EXPECT_EQ(guard.counters().withdrawn_pending, 1u);
  EXPECT_EQ(guard.counters().withdrawn_answered_before, 2u);
  EXPECT_EQ(guard.counters().withdrawn_untracked, 1u);
  // The pending one gets its abort.
  ASSERT_EQ(guard.on_gateway_down(1).size(), 1u);
  EXPECT_EQ(guard.counters().aborted_in_flight, guard.counters().withdrawn_pending);
}

TEST(SdoLinkGuard, UnknownNodesAndOtherFramesPassUntouched) {
  SdoLinkGuard guard;
  auto down = [](auto) { return false; };
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, down).forward);  // nobody owns node 34 yet
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  EXPECT_TRUE(guard.on_surface_frame(can::Frame::standard(0x000, {0x01, 0x22}), down).forward);
  EXPECT_TRUE(guard.on_surface_frame(can::Frame::standard(0x222, {1, 2}), down).forward);
  EXPECT_TRUE(
      guard.on_surface_frame(can::Frame::standard(0x622, {0x40, 0x18, 0x10}), down).forward);
  EXPECT_EQ(guard.owner_of(34), 1u);
  EXPECT_FALSE(guard.owner_of(35));
  EXPECT_EQ(guard.counters().aborted_at_once, 0u);
}

// The backbone gave up a request (too old, or queued for a gateway process that is gone): its
// master gets one abort if it still waits, none if it has its answer.
TEST(SdoLinkGuard, ADiscardedRequestIsAbortedOnlyWhileItsMasterStillWaits) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  auto up = [](auto) { return true; };
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, up).forward);
  const auto abort = guard.on_request_discarded(kRead1018);
  ASSERT_TRUE(abort);
  EXPECT_EQ(*abort, abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_FALSE(guard.on_request_discarded(kRead1018)) << "aborted twice";
  // A late answer to the aborted request is not passed on.
  EXPECT_FALSE(
      guard.on_gateway_frame(1, can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4})));
  // Answered: nothing to abort.
  EXPECT_TRUE(guard.on_surface_frame(kRead1018, up).forward);
  (void)guard.on_gateway_frame(1,
                               can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4}));
  EXPECT_FALSE(guard.on_request_discarded(kRead1018));
  // A node no gateway has claimed is not followed: its request is aborted, naming its object.
  const can::Frame write_unknown =
      can::Frame::standard(0x650, {0x2B, 0x17, 0x10, 0x00, 0xC8, 0x00, 0, 0});
  const auto unknown = guard.on_request_discarded(write_unknown);
  ASSERT_TRUE(unknown);
  EXPECT_EQ(*unknown, abort_of(0x5D0, 0x1017, 0x00));
  EXPECT_EQ(guard.counters().aborted_discarded, 2u);
  // Not a request, or the master's own abort: nothing.
  EXPECT_FALSE(guard.on_request_discarded(kHeartbeat34));
  EXPECT_FALSE(guard.on_request_discarded(abort_of(0x622, 0x1018, 0x01)));
}
}  // namespace
}  // namespace canbridge::bridge

#include <deque>
#include <random>

#include "bridge/gateway_table.hpp"

namespace canbridge::bridge {
namespace {

// The surface's SDO path in miniature, as Surface wires it: the table admits gateways and their
// claims make the guard own their nodes; a request passes the guard, then waits in its owner's
// queue; a link loss withdraws that queue and the guard aborts what was in flight.
class SurfaceSdoModel {
 public:
  explicit SurfaceSdoModel(bool claims_known) : claims_known_(claims_known) {
    for (ModuleId module : {ModuleId{1}, ModuleId{2}}) {
      NodeMap map;
      EXPECT_TRUE(map.add_module(module, NodeMap::default_pairs(module)).empty());
      hellos_.push_back({"gw-" + std::to_string(module), module, {module}, claims_of(map), {}});
      link_up(module - 1);
    }
  }

  void link_up(std::size_t g) {
    const auto admitted = table_.admit(hellos_[g]);
    ASSERT_TRUE(admitted.id);
    if (claims_known_) guard_.note_claims(*admitted.id, *hellos_[g].claims);
    table_.set_connected(*admitted.id, true);
    up_[g] = true;
  }
  void link_down(std::size_t g) {
    if (!up_[g]) return;
    up_[g] = false;
    table_.set_connected(static_cast<GatewayTable::GatewayId>(g), false);
    queue_[g].clear();  // withdrawn: the master is told below
    for (const can::Frame& abort : guard_.on_gateway_down(static_cast<SdoLinkGuard::GatewayId>(g)))
      to_master(abort);
  }
  // The master sends a request to surface node `node` (nothing pending for it).
  void request(NodeId node) {
    ASSERT_FALSE(waiting_[node]);
    waiting_[node] = true;
    ++requests_;
    const can::Frame frame = can::Frame::standard(0x600 + node, {0x40, 0x00, 0x10, 0, 0, 0, 0, 0});
    const auto verdict = guard_.on_surface_frame(frame, [&](auto g) { return up_[g]; });
    if (verdict.reply) to_master(*verdict.reply);
    if (!verdict.forward) return;
    const auto route = table_.route(frame);
    ASSERT_EQ(route.kind, GatewayTable::Route::one);
    queue_[route.gateway].push_back(frame);
  }
  // The gateway puts its oldest request on the bus; the node answers at once.
  void deliver(std::size_t g) {
    if (!up_[g] || queue_[g].empty()) return;
    const NodeId node = static_cast<NodeId>(queue_[g].front().id - 0x600);
    queue_[g].pop_front();
    const can::Frame answer = can::Frame::standard(0x580 + node, {0x43, 0x00, 0x10, 0, 1, 0, 0, 0});
    if (guard_.on_gateway_frame(static_cast<SdoLinkGuard::GatewayId>(g), answer)) to_master(answer);
  }

  std::uint64_t requests() const { return requests_; }
  std::uint64_t answers() const { return answers_; }
  std::uint64_t aborts() const { return aborts_; }
  std::uint64_t doubles() const { return doubles_; }
  std::size_t waiting() const {
    return static_cast<std::size_t>(std::count(waiting_.begin(), waiting_.end(), true));
  }
  bool waiting(NodeId node) const { return waiting_[node]; }

 private:
  void to_master(const can::Frame& frame) {
    const NodeId node = static_cast<NodeId>(frame.id - 0x580);
    if (!waiting_[node]) {
      ++doubles_;
      return;
    }
    waiting_[node] = false;
    ++(frame.data[0] == 0x80 ? aborts_ : answers_);
  }

  bool claims_known_;
  GatewayTable table_{"surface", {{"gw-1", {1}, {}}, {"gw-2", {2}, {}}}, false};
  SdoLinkGuard guard_;
  std::vector<GatewayTable::Hello> hellos_;
  std::vector<bool> up_ = std::vector<bool>(2);
  std::vector<std::deque<can::Frame>> queue_ = std::vector<std::deque<can::Frame>>(2);
  std::array<bool, 128> waiting_{};
  std::uint64_t requests_ = 0, answers_ = 0, aborts_ = 0, doubles_ = 0;
};

// Random requests to nodes that never sent a frame (heartbeats off), deliveries and link cuts:
// every request ends in exactly one answer or one abort, none vanishes, none ends twice.
void run_request_fates(SurfaceSdoModel& model, std::uint32_t seed) {
  std::mt19937 rng(seed);
  auto pick = [&](std::uint32_t n) {
    return std::uniform_int_distribution<std::uint32_t>(0, n - 1)(rng);
  };
  for (int step = 0; step < 20000; ++step) {
    const std::uint32_t action = pick(100);
    const std::size_t g = pick(2);
    if (action < 50) {
      const auto node = static_cast<NodeId>(33 + 32 * g + pick(31));
      if (!model.waiting(node)) model.request(node);
    } else if (action < 90) {
      model.deliver(g);
    } else if (action < 95) {
      model.link_down(g);
    } else {
      model.link_up(g);
    }
  }
  model.link_down(0);  // the end: both links lost with requests still queued or in flight
  model.link_down(1);
}

TEST(SdoRequestFate, EveryAcceptedRequestIsAnsweredOrAbortedExactlyOnce) {
  for (std::uint32_t seed : {1u, 2u, 3u}) {
    SurfaceSdoModel model(true);
    run_request_fates(model, seed);
    EXPECT_GT(model.requests(), 1000u);
    EXPECT_GT(model.aborts(), 10u) << "the cuts must catch requests in flight";
    EXPECT_EQ(model.waiting(), 0u) << "requests vanished (seed " << seed << ")";
    EXPECT_EQ(model.answers() + model.aborts(), model.requests());
    EXPECT_EQ(model.doubles(), 0u);
  }
}

TEST(SdoRequestFate, WithoutClaimsRequestsToSilentNodesVanishAtACut) {
  // What the claims fix: a guard that only learns owners from traffic never saw these nodes.
  SurfaceSdoModel model(false);
  run_request_fates(model, 1);
  EXPECT_GT(model.waiting(), 0u);
}

// Issue 14, "no SDO request vanishes": an answer to a request executed just before a link cut
// (aborted toward the master) must not pass as the answer to the master's next request.
class SdoLinkGuardStale : public ::testing::Test {
 protected:
  void SetUp() override { (void)guard.on_gateway_frame(1, kHeartbeat34); }
  bool send(std::initializer_list<std::uint8_t> data) {
    return guard.on_surface_frame(can::Frame::standard(0x622, data), up).forward;
  }
  bool answer(std::initializer_list<std::uint8_t> data) {
    return guard.on_gateway_frame(1, can::Frame::standard(0x5A2, data));
  }
  SdoLinkGuard guard;
  static bool up(SdoLinkGuard::GatewayId /*gateway*/) { return true; }
};

TEST_F(SdoLinkGuardStale, AnUploadAnswerWhileADownloadOfTheSameObjectIsPendingIsDropped) {
  ASSERT_TRUE(send({0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0}));     // upload 2000h
  ASSERT_EQ(guard.on_gateway_down(1).size(), 1u);              // aborted toward the master
  ASSERT_TRUE(send({0x23, 0x00, 0x20, 0x00, 7, 0, 0, 0}));     // download 2000h, link back
  EXPECT_FALSE(answer({0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}));  // the upload's late answer
  EXPECT_EQ(guard.counters().stale_responses_dropped, 1u);
  EXPECT_TRUE(answer({0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}));  // the download's answer
  // Nothing pending: another master's answer on the module bus passes (transparency).
  EXPECT_TRUE(answer({0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}));
  EXPECT_EQ(guard.counters().stale_responses_dropped, 1u);
}

TEST_F(SdoLinkGuardStale, ADownloadAnswerWhileAnUploadIsPendingIsDropped) {
  ASSERT_TRUE(send({0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0}));
  EXPECT_FALSE(answer({0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}));
  EXPECT_TRUE(answer({0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}));
}

TEST_F(SdoLinkGuardStale, AnAnswerNamingAnotherObjectIsDropped) {
  ASSERT_TRUE(send({0x40, 0x00, 0x20, 0x01, 0, 0, 0, 0}));     // upload 2000h sub 1
  EXPECT_FALSE(answer({0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}));  // sub 0
  EXPECT_FALSE(answer({0x43, 0x01, 0x20, 0x01, 1, 2, 3, 4}));  // 2001h
  EXPECT_TRUE(answer({0x43, 0x00, 0x20, 0x01, 1, 2, 3, 4}));   // its own
  EXPECT_EQ(guard.counters().stale_responses_dropped, 2u);
}

TEST_F(SdoLinkGuardStale, AnAbortAlwaysAnswersThePendingRequest) {
  ASSERT_TRUE(send({0x23, 0x00, 0x20, 0x00, 7, 0, 0, 0}));
  EXPECT_TRUE(answer({0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x02, 0x06}));
}

// Issue 27: the node's abort of a request executed just before a cut (the master saw
// 0x05040000) crossed once the link was back, while the master waited on a newer request, and
// reached the master as the newer request's answer.
TEST_F(SdoLinkGuardStale, AnAbortNamingAnotherObjectIsAnOlderRequestsAndDropped) {
  ASSERT_TRUE(send({0x23, 0x01, 0x30, 0x07, 7, 0, 0, 0}));  // download 3001h sub 7
  ASSERT_EQ(guard.on_gateway_down(1).size(), 1u);           // aborted toward the master
  ASSERT_TRUE(send({0x40, 0x01, 0x30, 0x08, 0, 0, 0, 0}));  // upload 3001h sub 8, link back
  EXPECT_FALSE(answer({0x80, 0x01, 0x30, 0x07, 0x00, 0x00, 0x02, 0x06}));  // the old abort
  EXPECT_EQ(guard.counters().stale_responses_dropped, 1u);
  EXPECT_TRUE(answer({0x80, 0x01, 0x30, 0x08, 0x00, 0x00, 0x02, 0x06}));  // its own
  // An abort naming no object (some servers send none) still ends the pending request.
  ASSERT_TRUE(send({0x40, 0x01, 0x30, 0x09, 0, 0, 0, 0}));
  EXPECT_TRUE(answer({0x80, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, 0x05}));
}

TEST_F(SdoLinkGuardStale, ANodeTheMasterNeverAskedPassesEverything) {
  EXPECT_TRUE(answer({0x43, 0x00, 0x20, 0x00, 1, 2, 3, 4}));
  EXPECT_TRUE(answer({0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0}));
}

TEST_F(SdoLinkGuardStale, SegmentAnswersPassOnlyForTheOpenSegmentedTransferAndItsToggle) {
  // Segmented upload of 1008h: initiate, segments toggling 0, 1.
  ASSERT_TRUE(send({0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0}));
  EXPECT_FALSE(answer({0x00, 'a', 'b', 'c', 'd', 'e', 'f', 'g'}));  // a segment: none asked
  EXPECT_TRUE(answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0}));
  ASSERT_TRUE(send({0x60, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_FALSE(answer({0x20, 0x08, 0x10, 0x00, 0, 0, 0, 0}));       // download segment class
  EXPECT_FALSE(answer({0x10, 'a', 'b', 'c', 'd', 'e', 'f', 'g'}));  // wrong toggle
  EXPECT_TRUE(answer({0x00, 'a', 'b', 'c', 'd', 'e', 'f', 'g'}));
  ASSERT_TRUE(send({0x70, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_TRUE(answer({0x17, 'h', 'i', 'j', 0, 0, 0, 0}));
  // Segmented download: initiate answered by scs 3, segments by scs 1.
  ASSERT_TRUE(send({0x21, 0x00, 0x21, 0x00, 9, 0, 0, 0}));
  EXPECT_TRUE(answer({0x60, 0x00, 0x21, 0x00, 0, 0, 0, 0}));
  ASSERT_TRUE(send({0x00, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_FALSE(answer({0x00, 1, 2, 3, 4, 5, 6, 7}));  // upload segment class
  EXPECT_TRUE(answer({0x20, 0, 0, 0, 0, 0, 0, 0}));
  ASSERT_TRUE(send({0x1B, 8, 9, 0, 0, 0, 0, 0}));
  EXPECT_TRUE(answer({0x30, 0, 0, 0, 0, 0, 0, 0}));
  EXPECT_EQ(guard.counters().stale_responses_dropped, 4u);
}

TEST_F(SdoLinkGuardStale, BlockDownloadPassesItsInitiateAcksAndEnd) {
  ASSERT_TRUE(send({0xC6, 0x00, 0x21, 0x00, 14, 0, 0, 0}));     // initiate, crc, size
  EXPECT_FALSE(answer({0x60, 0x00, 0x21, 0x00, 0, 0, 0, 0}));   // not a block answer
  EXPECT_TRUE(answer({0xA4, 0x00, 0x21, 0x00, 127, 0, 0, 0}));  // blksize 127
  ASSERT_TRUE(send({0x01, 1, 2, 3, 4, 5, 6, 7}));               // segment 1
  ASSERT_TRUE(send({0x82, 8, 9, 10, 11, 12, 13, 14}));          // segment 2, last
  EXPECT_TRUE(answer({0xA2, 2, 127, 0, 0, 0, 0, 0}));           // ack
  ASSERT_TRUE(send({0xC1, 0x34, 0x12, 0, 0, 0, 0, 0}));         // end, crc
  EXPECT_TRUE(answer({0xA1, 0, 0, 0, 0, 0, 0, 0}));             // end response
}

TEST_F(SdoLinkGuardStale, BlockUploadPassesEverySegmentOfTheServer) {
  ASSERT_TRUE(send({0xA4, 0x00, 0x21, 0x00, 127, 0, 0, 0}));   // initiate, crc, blksize
  EXPECT_FALSE(answer({0x60, 0x00, 0x21, 0x00, 0, 0, 0, 0}));  // a download's answer
  EXPECT_TRUE(answer({0xC6, 0x00, 0x21, 0x00, 14, 0, 0, 0}));  // initiate response
  ASSERT_TRUE(send({0xA3, 0, 0, 0, 0, 0, 0, 0}));              // start
  EXPECT_TRUE(answer({0x01, 1, 2, 3, 4, 5, 6, 7}));            // segments: any first byte
  EXPECT_TRUE(answer({0x82, 8, 9, 10, 11, 12, 13, 14}));
  ASSERT_TRUE(send({0xA2, 2, 127, 0, 0, 0, 0, 0}));        // ack
  EXPECT_TRUE(answer({0xC1, 0x34, 0x12, 0, 0, 0, 0, 0}));  // end
  ASSERT_TRUE(send({0xA1, 0, 0, 0, 0, 0, 0, 0}));          // end: no answer
  EXPECT_TRUE(guard.on_gateway_down(1).empty());           // nothing in flight after the end
}

TEST_F(SdoLinkGuardStale, ABlockUploadTheServerSwitchesToTheUploadProtocolPasses) {
  ASSERT_TRUE(send({0xA4, 0x00, 0x21, 0x00, 127, 4, 0, 0}));  // protocol switch threshold 4
  EXPECT_TRUE(answer({0x43, 0x00, 0x21, 0x00, 1, 2, 3, 4}));
}

// Issue 27: a request in flight at a cut may have been executed; its answer, resent by the
// gateway on the next link, is delivered if it comes in time (the master's time-out of 1000 ms
// here: until 800 ms after the request), else the abort goes out then, before the master's own
// time-out.
using namespace std::chrono_literals;

class SdoLinkGuardRecovery : public ::testing::Test {
 protected:
  SdoLinkGuardRecovery() { (void)guard.on_gateway_frame(1, kHeartbeat34); }
  bool up = true;
  SdoLinkGuard guard{{.transfer_open_for = 1000ms, .answer_wait = 800ms}};
  const SdoLinkGuard::Clock::time_point t0{std::chrono::hours(1)};
  const can::Frame answer_1018 = can::Frame::standard(0x5A2, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4});
  bool send(const can::Frame& request, SdoLinkGuard::Clock::time_point at) {
    return guard
        .on_surface_frame(
            request, [this](auto) { return up; }, at)
        .forward;
  }
};

TEST_F(SdoLinkGuardRecovery, AnAnswerTheNextLinkBringsInTimeReachesTheMaster) {
  ASSERT_TRUE(send(kRead1018, t0));
  up = false;
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 300ms).empty());  // no abort yet
  EXPECT_EQ(guard.next_deadline(), t0 + 800ms);
  up = true;
  EXPECT_TRUE(guard.on_gateway_frame(1, answer_1018));  // resent by the gateway, new link
  EXPECT_EQ(guard.counters().answers_recovered, 1u);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  EXPECT_TRUE(guard.on_time(t0 + 800ms).empty());
  EXPECT_EQ(guard.counters().aborted_in_flight, 0u);
}

TEST_F(SdoLinkGuardRecovery, WithoutItsAnswerInTimeTheMasterGetsTheAbortBeforeItsOwnTimeOut) {
  ASSERT_TRUE(send(kRead1018, t0));
  up = false;
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 300ms).empty());
  EXPECT_TRUE(guard.on_time(t0 + 799ms).empty());
  const auto aborts = guard.on_time(t0 + 800ms);
  ASSERT_EQ(aborts.size(), 1u);
  EXPECT_EQ(aborts[0], abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_EQ(guard.counters().aborted_in_flight, 1u);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  up = true;
  EXPECT_FALSE(guard.on_gateway_frame(1, answer_1018));  // after the abort: never delivered
  EXPECT_EQ(guard.counters().late_responses_dropped, 1u);
  EXPECT_EQ(guard.counters().answers_recovered, 0u);
}

TEST_F(SdoLinkGuardRecovery, ALinkThatDropsAfterTheWaitAbortsAtOnce) {
  ASSERT_TRUE(send(kRead1018, t0));
  up = false;
  ASSERT_EQ(guard.on_gateway_down(1, t0 + 800ms).size(), 1u);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  EXPECT_FALSE(send(kRead1018, t0 + 1000ms));  // the link is known down: aborted at once
  EXPECT_EQ(guard.counters().aborted_at_once, 1u);
}

TEST_F(SdoLinkGuardRecovery, ANewerRequestOfTheMasterEndsTheWait) {
  ASSERT_TRUE(send(kRead1018, t0));
  up = false;
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 300ms).empty());
  // The master timed out itself (python-canopen: 0.3 s) and asks again: aborted at once, and the
  // old request is not aborted later (its master has moved on).
  const auto again = guard.on_surface_frame(
      kRead1018, [](auto) { return false; }, t0 + 400ms);
  ASSERT_TRUE(again.reply);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  EXPECT_TRUE(guard.on_time(t0 + 900ms).empty());
}

// Issue 27, a flake of system_sdo_noisy: 24 requests reached their nodes over a live link whose
// line kept corrupting the answers' batch; the gateway gave the answers up after
// reliable_max_age_ms, the link never died, and the guard, which only acted on a lost link, left
// the master to its own time-out. Removing the deadline of requests on a live link
// (SdoLinkGuard::on_surface_frame) makes this test fail.
TEST_F(SdoLinkGuardRecovery, AnAnswerOverdueOnALiveLinkGetsTheAbortBeforeTheMastersTimeOut) {
  ASSERT_TRUE(send(kRead1018, t0));
  EXPECT_EQ(guard.next_deadline(), t0 + 800ms);
  std::vector<canopen::NodeId> withdrawn;
  const auto withdraw = [&](canopen::NodeId node) {
    // Called while the request is still pending, so that it is accounted as the pending one.
    guard.on_request_withdrawn(kRead1018);
    withdrawn.push_back(node);
  };
  EXPECT_TRUE(guard.on_time(t0 + 799ms, withdraw).empty());
  EXPECT_TRUE(withdrawn.empty());
  const auto aborts = guard.on_time(t0 + 800ms, withdraw);
  ASSERT_EQ(aborts.size(), 1u);
  EXPECT_EQ(aborts[0], abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_EQ(withdrawn, std::vector<canopen::NodeId>{34});  // before the abort: none runs later
  EXPECT_EQ(guard.counters().aborted_overdue, 1u);
  EXPECT_EQ(guard.counters().aborted_in_flight, 0u);
  EXPECT_EQ(guard.counters().withdrawn_pending, 1u);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  // The answer, should it come after all, is late: the master was told.
  EXPECT_FALSE(guard.on_gateway_frame(1, answer_1018));
  EXPECT_EQ(guard.counters().late_responses_dropped, 1u);
  // And a link that drops afterwards owes the master nothing more.
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 900ms).empty());
}

TEST_F(SdoLinkGuardRecovery, AnAnswerInTimeOnALiveLinkEndsTheDeadline) {
  ASSERT_TRUE(send(kRead1018, t0));
  EXPECT_TRUE(guard.on_gateway_frame(1, answer_1018));
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  EXPECT_TRUE(guard.on_time(t0 + 800ms).empty());
  EXPECT_EQ(guard.counters().answers_recovered, 0u);  // delivered, not recovered
  // Each request of the master has its own deadline, counted from when it went out.
  ASSERT_TRUE(send(kRead1018, t0 + 1000ms));
  EXPECT_EQ(guard.next_deadline(), t0 + 1800ms);
  // The link drops: the request waits for the next one until the same deadline.
  up = false;
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 1500ms).empty());
  EXPECT_EQ(guard.next_deadline(), t0 + 1800ms);
  ASSERT_EQ(guard.on_time(t0 + 1800ms).size(), 1u);
  EXPECT_EQ(guard.counters().aborted_in_flight, 1u);
  EXPECT_EQ(guard.counters().aborted_overdue, 0u);
}

TEST_F(SdoLinkGuardRecovery, EachFrameOfABlockDownloadMovesItsDeadline) {
  const auto send_bytes = [&](std::initializer_list<std::uint8_t> bytes,
                              SdoLinkGuard::Clock::time_point at) {
    return send(can::Frame::standard(0x622, bytes), at);
  };
  ASSERT_TRUE(send_bytes({0xC6, 0x00, 0x1F, 0x01, 0, 1, 0, 0}, t0));  // initiate, 256 bytes
  EXPECT_TRUE(guard.on_gateway_frame(
      1, can::Frame::standard(0x5A2, {0xA4, 0x00, 0x1F, 0x01, 127, 0, 0, 0})));
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
  ASSERT_TRUE(send_bytes({0x01, 1, 2, 3, 4, 5, 6, 7}, t0 + 10ms));   // segment 1
  ASSERT_TRUE(send_bytes({0x02, 1, 2, 3, 4, 5, 6, 7}, t0 + 500ms));  // segment 2
  EXPECT_EQ(guard.next_deadline(), t0 + 1300ms);
}

TEST(SdoLinkGuard, WithoutAnAnswerWaitNoRequestHasADeadline) {
  SdoLinkGuard guard;
  (void)guard.on_gateway_frame(1, kHeartbeat34);
  ASSERT_TRUE(guard.on_surface_frame(kRead1018, [](auto) { return true; }).forward);
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
}

TEST_F(SdoLinkGuardRecovery, ANewGatewayProcessEndsTheWaitAtOnce) {
  ASSERT_TRUE(send(kRead1018, t0));
  up = false;
  EXPECT_TRUE(guard.on_gateway_down(1, t0 + 300ms).empty());
  EXPECT_TRUE(guard.on_gateway_restart(2, t0 + 400ms).empty());  // another gateway's
  const auto aborts = guard.on_gateway_restart(1, t0 + 400ms);
  ASSERT_EQ(aborts.size(), 1u);  // the old process's answer is lost with it
  EXPECT_EQ(aborts[0], abort_of(0x5A2, 0x1018, 0x01));
  EXPECT_EQ(guard.next_deadline(), std::nullopt);
}

}  // namespace
}  // namespace canbridge::bridge
