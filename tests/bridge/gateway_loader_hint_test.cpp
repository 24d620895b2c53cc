// A qd node's loader boot-up (0x720 + n) on a module configured as cia301 reads as the boot-up of
// an unmapped node 32 + n: the gateway says once what it probably is and how to configure it
// (issue 28's phantom node), and says nothing for a cia301 node that merely has no surface id.
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include <boost/asio/io_context.hpp>
#include <chrono>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bridge/gateway.hpp"
#include "can/virtual_bus.hpp"
#include "routing/node_map.hpp"
#include "tests/support/bus_recorder.hpp"
#include "tests/support/event_loop.hpp"

namespace canbridge::bridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;

constexpr ModuleId kModule = 1;

std::size_t occurrences(const std::string& text, const std::string& needle) {
  std::size_t n = 0;
  for (auto at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

class LoaderHint : public ::testing::Test {
 protected:
  void SetUp() override {
    sink_ = std::make_shared<spdlog::sinks::ostream_sink_st>(warnings_);
    sink_->set_level(spdlog::level::info);  // the hint is an info line
    spdlog::default_logger()->sinks().push_back(sink_);
  }
  void TearDown() override {
    auto& sinks = spdlog::default_logger()->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), sink_), sinks.end());
  }

  // Boot-ups on the module bus of a gateway whose module 1 has the given profile, until the
  // gateway's node table has seen them all.
  std::string warnings_after(IdProfile profile, const std::vector<Frame>& boot_ups,
                             const std::vector<canopen::NodeId>& expected_known) {
    boost::asio::io_context io{1};
    can::VirtualBus module_bus{io.get_executor(), "module"};
    test::BusRecorder nodes{io, module_bus.connect("nodes")};
    NodeMap map;
    EXPECT_TRUE(map.add_module(kModule, {{2, 2}}, profile).empty());
    std::vector<GatewayModule> modules(1);
    modules[0].id = kModule;
    modules[0].bus = module_bus.connect("gateway");
    Gateway gateway(io.get_executor(), "gw", std::move(map), std::move(modules), BackboneTuning{});
    gateway.start();
    for (const Frame& f : boot_ups) EXPECT_TRUE(nodes.send(f));
    EXPECT_TRUE(test::run_until(io, [&] {
      for (const canopen::NodeId local : expected_known) {
        if (gateway.node_table().node(0, local) == nullptr) return false;
      }
      return true;
    }));
    gateway.stop();
    sink_->flush();
    return warnings_.str();
  }

  std::ostringstream warnings_;
  std::shared_ptr<spdlog::sinks::ostream_sink_st> sink_;
};

// Fails if the hint is missing, or repeated for every loader boot-up.
TEST_F(LoaderHint, QdLoaderBootUpsOnACia301ModuleAreNamedOnce) {
  const std::string log =
      warnings_after(IdProfile::cia301,
                     {Frame::standard(0x722, {0x00}), Frame::standard(0x725, {0x00})}, {34, 37});
  EXPECT_EQ(occurrences(log, "profile: qd"), 1u) << log;
  EXPECT_NE(log.find("0x722 (node 34)"), std::string::npos) << log;
  EXPECT_NE(log.find("node 2's qd loader"), std::string::npos) << log;
  EXPECT_EQ(log.find("[warning]"), std::string::npos) << "a hint, not a warning: " << log;
  EXPECT_NE(log.find("[info]"), std::string::npos) << log;
}

// A mapped node's boot-up, and a node above 63 (no loader id), get no hint; nor does a qd module,
// where 0x720 + n is understood.
TEST_F(LoaderHint, NoHintWhereTheBootUpIsNoLoaderOfAMisreadQdNode) {
  EXPECT_EQ(
      warnings_after(IdProfile::cia301,
                     {Frame::standard(0x702, {0x00}), Frame::standard(0x750, {0x00})}, {2, 80})
          .find("profile: qd"),
      std::string::npos);
  EXPECT_EQ(
      warnings_after(IdProfile::qd, {Frame::standard(0x722, {0x00})}, {2}).find("profile: qd"),
      std::string::npos);
}

}  // namespace
}  // namespace canbridge::bridge
