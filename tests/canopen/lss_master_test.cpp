// The LSS master services against the simulated cia301 node's LSS slave (sim/lss_slave): the
// 309-3 commissioning sequence, error answers, timeouts and answers that are not ours.
#include "canopen/lss_master.hpp"

#include <gtest/gtest.h>

#include <stdexcept>
#include <vector>

#include "sim/lss_slave.hpp"
#include "sim/sim_node.hpp"

namespace canbridge::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Frames = std::vector<Frame>;
using TimePoint = LssMaster::TimePoint;

const TimePoint t0 = TimePoint{} + 1h;
constexpr auto kTimeout = 100ms;
const lss::Address kAddress{0x000001A2, 0x00001234, 0x00010002, 0xCAFEF00D};

sim::NodeSpec cia301(NodeId id) {
  sim::NodeSpec c;
  c.kind = sim::NodeKind::cia301;
  c.node_id = id;
  c.identity = {kAddress.vendor, kAddress.product, kAddress.revision, kAddress.serial};
  c.heartbeat_ms = 0;
  return c;
}

// A bus with simulated nodes: every request reaches every node, every answer the master.
struct Bus {
  std::vector<std::unique_ptr<sim::SimNode>> nodes;
  TimePoint now = t0;
  Frames from_nodes;  // everything but LSS answers (boot-ups after a reset)

  sim::SimNode& add(const sim::NodeSpec& spec) {
    nodes.push_back(std::make_unique<sim::SimNode>(spec));
    nodes.back()->boot(now);
    return *nodes.back();
  }
  Frames send(const Frames& frames) {
    Frames answers;
    for (const auto& f : frames) {
      for (auto& n : nodes) {
        for (const auto& a : n->on_frame(f, now)) {
          (a.id == cob::lss_slave ? answers : from_nodes).push_back(a);
        }
      }
    }
    return answers;
  }
  LssResult run(LssMaster m) {
    Frames out;
    m.start(now, out);
    for (const auto& a : send(out)) m.on_frame(a, now);
    if (!m.finished()) {
      now = m.deadline();
      m.on_timeout(now);
    }
    EXPECT_TRUE(m.finished());
    return m.result();
  }
};

TEST(LssMaster, CommissionsANodeByItsAddressNewIdAfterReset) {
  Bus bus;
  auto& node = bus.add(cia301(10));
  auto other = cia301(11);
  other.identity.serial = 0x12345678;
  auto& bystander = bus.add(other);

  // lss_switch_sel: only the node with that address enters configuration state and answers.
  EXPECT_TRUE(bus.run(LssMaster::switch_selective(kAddress, kTimeout)).ok());
  EXPECT_TRUE(node.lss()->in_configuration());
  EXPECT_FALSE(bystander.lss()->in_configuration());
  EXPECT_EQ(bus.now, t0);  // answered, no timeout waited

  // lss_inquire_addr 0..3 and lss_get_node.
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::vendor, kTimeout)).value, kAddress.vendor);
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::product, kTimeout)).value, kAddress.product);
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::revision, kTimeout)).value, kAddress.revision);
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::serial, kTimeout)).value, kAddress.serial);
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::node_id, kTimeout)).value, 10u);

  // lss_set_node 42, lss_store, lss_switch_glob 0.
  EXPECT_TRUE(bus.run(LssMaster::configure_node_id(42, kTimeout)).ok());
  EXPECT_TRUE(bus.run(LssMaster::store_configuration(kTimeout)).ok());
  EXPECT_EQ(node.lss()->stored_node_id(), 42);
  EXPECT_TRUE(bus.run(LssMaster::switch_global(false, kTimeout)).ok());
  EXPECT_FALSE(node.lss()->in_configuration());
  EXPECT_EQ(node.id(), 10);  // CiA 305: active at the next reset only

  bus.send({Frame::standard(0x000, {0x82, 10})});  // reset communication
  EXPECT_EQ(node.id(), 42);
  ASSERT_FALSE(bus.from_nodes.empty());
  EXPECT_EQ(bus.from_nodes.back(), Frame::standard(0x700 + 42, {0x00}));
  EXPECT_EQ(bystander.id(), 11);
}

TEST(LssMaster, SwitchGlobalHasNoAnswerAndSucceedsOnceWritten) {
  Bus bus;
  bus.add(cia301(3));
  LssMaster m = LssMaster::switch_global(true, kTimeout);
  Frames out;
  m.start(bus.now, out);
  EXPECT_TRUE(m.finished());
  EXPECT_TRUE(m.result().ok());
  EXPECT_EQ(out, (Frames{Frame::standard(0x7E5, {0x04, 0x01, 0, 0, 0, 0, 0, 0})}));
  EXPECT_TRUE(bus.send(out).empty());
  EXPECT_TRUE(bus.nodes[0]->lss()->in_configuration());
}

TEST(LssMaster, WrongAddressTimesOutAndSelectsNobody) {
  Bus bus;
  auto& node = bus.add(cia301(3));
  auto wrong = kAddress;
  wrong.revision = 0x00020000;
  const auto r = bus.run(LssMaster::switch_selective(wrong, kTimeout));
  EXPECT_EQ(r.error, LssError::timeout);
  EXPECT_EQ(bus.now, t0 + kTimeout);
  EXPECT_FALSE(node.lss()->in_configuration());
  // Nobody in configuration state: inquiries time out too.
  EXPECT_EQ(bus.run(LssMaster::inquire(LssInquiry::node_id, kTimeout)).error, LssError::timeout);
}

TEST(LssMaster, ErrorCodesOfTheConfigureAndStoreAnswers) {
  Bus bus;
  bus.add(cia301(3));
  ASSERT_TRUE(bus.run(LssMaster::switch_global(true, kTimeout)).ok());
  // The slave's range check, seen through a request the master would not build (0x80).
  LssMaster configure = LssMaster::configure_node_id(5, kTimeout);
  Frames out;
  configure.start(bus.now, out);
  out[0].data[1] = 0x80;
  for (const auto& a : bus.send(out)) configure.on_frame(a, bus.now);
  ASSERT_TRUE(configure.finished());
  EXPECT_EQ(configure.result().error, LssError::node_id_out_of_range);
  EXPECT_EQ(configure.result().answer_code, 1);

  // Answers decoded from frames: store without memory, storage failure, vendor-specific.
  const auto store_answer = [&](std::uint8_t code, std::uint8_t specific) {
    LssMaster m = LssMaster::store_configuration(kTimeout);
    Frames ignored;
    m.start(bus.now, ignored);
    m.on_frame(Frame::standard(0x7E4, {0x17, code, specific, 0, 0, 0, 0, 0}), bus.now);
    EXPECT_TRUE(m.finished());
    return m.result();
  };
  EXPECT_EQ(store_answer(1, 0).error, LssError::not_supported);
  EXPECT_EQ(store_answer(2, 0).error, LssError::storage_access);
  const auto specific = store_answer(0xFF, 0x33);
  EXPECT_EQ(specific.error, LssError::implementation_specific);
  EXPECT_EQ(specific.specific_code, 0x33);
  EXPECT_EQ(store_answer(7, 0).error, LssError::refused);
  EXPECT_TRUE(store_answer(0, 0).ok());
}

TEST(LssMaster, IgnoresAnswersToOtherServicesAndOtherFrames) {
  LssMaster m = LssMaster::inquire(LssInquiry::serial, kTimeout);
  Frames out;
  m.start(t0, out);
  EXPECT_EQ(out, (Frames{Frame::standard(0x7E5, {0x5D, 0, 0, 0, 0, 0, 0, 0})}));
  m.on_frame(Frame::standard(0x7E4, {0x5E, 0x05, 0, 0, 0, 0, 0, 0}), t0);  // node-id answer
  m.on_frame(Frame::standard(0x7E5, {0x5D, 1, 2, 3, 4, 0, 0, 0}), t0);     // a request
  m.on_frame(Frame::standard(0x5E4, {0x5D, 1, 2, 3, 4, 0, 0, 0}), t0);
  EXPECT_FALSE(m.finished());
  m.on_timeout(t0 + kTimeout - 1ms);  // early: nothing
  EXPECT_FALSE(m.finished());
  m.on_frame(Frame::standard(0x7E4, {0x5D, 0x0D, 0xF0, 0xFE, 0xCA, 0, 0, 0}), t0);
  ASSERT_TRUE(m.finished());
  EXPECT_EQ(m.result().value, 0xCAFEF00Du);
  EXPECT_EQ(m.deadline(), TimePoint::max());
}

TEST(LssMaster, SwitchSelectiveSendsTheFourPartsInOrder) {
  LssMaster m = LssMaster::switch_selective({1, 2, 3, 0x04030201}, kTimeout);
  Frames out;
  m.start(t0, out);
  EXPECT_EQ(out, (Frames{Frame::standard(0x7E5, {0x40, 1, 0, 0, 0, 0, 0, 0}),
                         Frame::standard(0x7E5, {0x41, 2, 0, 0, 0, 0, 0, 0}),
                         Frame::standard(0x7E5, {0x42, 3, 0, 0, 0, 0, 0, 0}),
                         Frame::standard(0x7E5, {0x43, 1, 2, 3, 4, 0, 0, 0})}));
  EXPECT_EQ(m.deadline(), t0 + kTimeout);
}

TEST(LssMaster, ConfigureNodeIdChecksItsArgument) {
  EXPECT_THROW(LssMaster::configure_node_id(0, kTimeout), std::invalid_argument);
  EXPECT_THROW(LssMaster::configure_node_id(128, kTimeout), std::invalid_argument);
  EXPECT_NO_THROW(LssMaster::configure_node_id(0xFF, kTimeout));
  EXPECT_EQ(make_error_code(LssError::timeout).category().name(), std::string("canopen.lss"));
}

}  // namespace
}  // namespace canbridge::canopen
