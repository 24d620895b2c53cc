// The simulated nodes on real vcan interfaces, driven by can-utils only: canbridge-sim runs a rig
// file, cansend plays the CANopen master, candump -L shows what the nodes put on the bus.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/process.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using test::ChildProcess;

const std::string kRig = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/sim_system/bench_rig.yaml";

void cansend(const std::string& bus, const std::string& frame) {
  auto r = test::run({"cansend", bus, frame});
  ASSERT_EQ(r.status, 0) << "cansend " << bus << " " << frame << ": " << r.output;
}

// candump -L line: "(1700000000.123456) vcan0 705#7F". Returns the seconds and the frame text.
struct DumpLine {
  double time = 0;
  std::string frame;  // "705#7F"
};
std::vector<DumpLine> parse_dump(const std::string& output, const std::string& prefix) {
  std::vector<DumpLine> lines;
  std::istringstream in(output);
  std::string line;
  while (std::getline(in, line)) {
    const auto open = line.find('(');
    const auto close = line.find(')');
    const auto space = line.rfind(' ');
    if (open != 0 || close == std::string::npos || space == std::string::npos) continue;
    DumpLine d{std::stod(line.substr(1, close - 1)), line.substr(space + 1)};
    if (d.frame.rfind(prefix, 0) == 0) lines.push_back(d);
  }
  return lines;
}

double median_interval_ms(const std::vector<DumpLine>& lines) {
  std::vector<double> gaps;
  for (std::size_t i = 1; i < lines.size(); ++i)
    gaps.push_back((lines[i].time - lines[i - 1].time) * 1000.0);
  if (gaps.empty()) return 0;
  std::sort(gaps.begin(), gaps.end());
  return gaps[gaps.size() / 2];
}

class SimRig : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dump_ = std::make_unique<ChildProcess>(std::vector<std::string>{"candump", "-L", "vcan0"});
    // candump is listening once it shows a frame sent after it started.
    for (int i = 0; i < 50 && !dump_->wait_for_line("vcan0 7FF#A5", 100ms); ++i) {
      cansend("vcan0", "7FF#A5");
    }
    sim_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{CANBRIDGE_SIM_BIN, kRig, "--stats-seconds", "0"});
    ASSERT_TRUE(sim_->wait_for_line("canbridge-sim: ready 2 nodes on 1 buses", 10s))
        << sim_->output();
  }
  static void TearDownTestSuite() {
    if (sim_) {
      EXPECT_EQ(sim_->stop(), 0) << sim_->output();
    }
    sim_.reset();
    dump_.reset();
  }
  // The next candump line containing `needle`, or a failure naming what was seen.
  static void expect_line(const std::string& needle) {
    EXPECT_TRUE(dump_->wait_for_line(needle, 5s)) << "no '" << needle << "' in:\n"
                                                  << dump_->output();
  }
  static inline std::unique_ptr<ChildProcess> dump_, sim_;
};

TEST_F(SimRig, BootUpOfEveryNode) {
  // In the rig file's order: the device (5), then the minimal node (3).
  expect_line("vcan0 705#00");
  expect_line("vcan0 703#00");
}

TEST_F(SimRig, ExpeditedReadOfVendorId) {
  cansend("vcan0", "605#4018100100000000");
  expect_line("vcan0 585#43181001A2010000");
}

TEST_F(SimRig, SegmentedUploadOfTheDeviceName) {
  const std::string expected = "canbridge simulated cia301 device";
  cansend("vcan0", "605#4008100000000000");
  // Initiate response: segmented (e = 0), size indicated, 33 bytes.
  expect_line("vcan0 585#4108100021000000");
  std::string received;
  for (int segment = 0; segment < 10; ++segment) {
    const std::size_t mark = dump_->output().size();
    const bool toggle = segment % 2 == 1;
    cansend("vcan0", toggle ? "605#7000000000000000" : "605#6000000000000000");
    ASSERT_TRUE(dump_->wait_for_line("vcan0 585#", 5s)) << dump_->output();
    const auto lines = parse_dump(dump_->output().substr(mark), "585#");
    ASSERT_FALSE(lines.empty());
    const std::string hex = lines.back().frame.substr(4);
    ASSERT_EQ(hex.size(), 16u) << hex;
    const unsigned command = std::stoul(hex.substr(0, 2), nullptr, 16);
    EXPECT_EQ((command & 0x10) != 0, toggle);
    const unsigned unused = (command >> 1) & 0x7;
    for (unsigned i = 1; i < 8 - unused; ++i) {
      received.push_back(static_cast<char>(std::stoul(hex.substr(2 * i, 2), nullptr, 16)));
    }
    if ((command & 0x01) != 0) break;
  }
  EXPECT_EQ(received, expected);
}

TEST_F(SimRig, HeartbeatPeriodChangeBy1017hWrite) {
  // 200 ms from the rig file, then 50 ms written over SDO.
  std::size_t mark = dump_->output().size();
  for (int i = 0; i < 5; ++i) expect_line("vcan0 705#");
  const double before = median_interval_ms(parse_dump(dump_->output().substr(mark), "705#"));
  cansend("vcan0", "605#2B17100032000000");
  expect_line("vcan0 585#6017100000000000");
  mark = dump_->output().size();
  for (int i = 0; i < 9; ++i) expect_line("vcan0 705#");
  const double after = median_interval_ms(parse_dump(dump_->output().substr(mark), "705#"));
  EXPECT_NEAR(before, 200.0, 40.0);
  EXPECT_NEAR(after, 50.0, 20.0);
  cansend("vcan0", "605#2B171000C8000000");  // back to 200 ms for the tests that follow
  expect_line("vcan0 585#60171000");
}

TEST_F(SimRig, NmtStartChangesTheHeartbeatStateByte) {
  expect_line("vcan0 703#7F");  // pre-operational
  cansend("vcan0", "000#0103");
  expect_line("vcan0 703#05");  // operational
  cansend("vcan0", "000#0203");
  expect_line("vcan0 703#04");   // stopped
  cansend("vcan0", "000#8000");  // broadcast: everyone back to pre-operational
  expect_line("vcan0 703#7F");
}

// The reference tool string of seeds/000: every module bus comes up with its nodes' boot-ups.
TEST(ToolStringRig, EveryModuleBusBootsItsNodes) {
  std::vector<std::unique_ptr<ChildProcess>> dumps;
  for (int bus = 1; bus <= 5; ++bus) {
    const std::string iface = "vcan" + std::to_string(bus);
    dumps.push_back(
        std::make_unique<ChildProcess>(std::vector<std::string>{"candump", "-L", iface}));
    for (int i = 0; i < 50 && !dumps.back()->wait_for_line(iface + " 7FF#A5", 100ms); ++i) {
      cansend(iface, "7FF#A5");
    }
  }
  ChildProcess sim({CANBRIDGE_SIM_BIN,
                    std::string(CANBRIDGE_SOURCE_DIR) + "/config/rigs/tool_string.yaml",
                    "--stats-seconds", "0"});
  ASSERT_TRUE(sim.wait_for_line("canbridge-sim: ready", 10s)) << sim.output();
  for (int bus = 1; bus <= 5; ++bus) {
    const std::string iface = "vcan" + std::to_string(bus);
    EXPECT_TRUE(dumps[bus - 1]->wait_for_line(iface + " 7", 5s))
        << "no boot-up or heartbeat on " << iface << ":\n"
        << dumps[bus - 1]->output();
  }
  EXPECT_EQ(sim.stop(), 0) << sim.output();
}

// canbridge-sim refuses what canbridge refuses, with the same exit status: a rig file that cannot
// be read is 2 (as a configuration file of canbridge), and so is an --interface for a bus the rig
// does not have, which would otherwise be ignored and leave the bus it was meant for elsewhere.
TEST(SimCommandLine, AMissingRigFileExitsTwoLikeCanbridge) {
  const auto r = test::run({CANBRIDGE_SIM_BIN, "/nonexistent/rig.yaml"});
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("/nonexistent/rig.yaml"), std::string::npos) << r.output;
}

TEST(SimCommandLine, AnInterfaceForABusTheRigLacksIsRefused) {
  const auto r = test::run({CANBRIDGE_SIM_BIN, kRig, "--interface", "nosuchbus=vcan0"});
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("--interface nosuchbus=vcan0"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("has no bus nosuchbus"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace canbridge
