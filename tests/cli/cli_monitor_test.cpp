// `canbridge dump` and `canbridge capture` fed by scripted monitor lines: decoded and filtered
// output, candump lines, drop notices, and a pcap that tshark dissects as CANopen.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "app/cli_reply.hpp"
#include "can/candump_log.hpp"
#include "tests/cli/cli_test_support.hpp"
#include "tests/cli/fake_endpoint.hpp"
#include "tests/support/tshark.hpp"

namespace canbridge::test {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
namespace exit_code = cli::exit_code;

// 2023-11-14 22:13:20 UTC + n µs.
std::string frame_line(int us, unsigned module, char dir, const std::string& frame) {
  return "FRAME " + std::to_string(1700000000000000LL + us) + " " + std::to_string(module) + " " +
         dir + " " + frame;
}

const std::vector<std::string> kNodes = {
    "[1] node net=2 module=1 gateway=g1 local=5 surface=5 profile=pdop kind=fpga "
    "state=operational hb_age_ms=10 boot_count=1 emcy=-",
    "[1] OK"};

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

TEST(CliDump, DecodesFramesWithTheModulesProfile) {
  FakeEndpoint endpoint(
      Script{{"[1] nodes", kNodes},
             {"[2] monitor",
              {"[2] OK", frame_line(1, 0, '<', "000#0105"), frame_line(2, 1, '>', "705#05"),
               frame_line(3, 1, '>', "1A5#0001020304050607"), frame_line(4, 1, '>', "1C5#08"),
               frame_line(5, 2, '>', "1A5#08")}}});
  const auto run = run_cli({"dump", "--count", "5", "--endpoint", endpoint.address()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] nodes", "[2] monitor"));
  EXPECT_THAT(
      lines_of(run.out),
      ElementsAre("22:13:20.000001 surface < 000#0105              NMT start node 5",
                  "22:13:20.000002 module1 > 705#05                heartbeat node 5 operational",
                  "22:13:20.000003 module1 > 1A5#0001020304050607  PDOP TPDO1 node 5 t=0 c=1: "
                  "00 01 02 03 04 05 06 07",
                  "22:13:20.000004 module1 > 1C5#08                PDOP TPDO1 node 5 t=1 c=0: 08 "
                  "-> packet of 9 bytes: 00 01 02 03 04 05 06 07 08",
                  // Module 2 is not a pdop module: the same id is node 37's TPDO1.
                  "22:13:20.000005 module2 > 1A5#08                TPDO1 node 37: 08"));
}

TEST(CliDump, FiltersByNodeAndKind) {
  FakeEndpoint endpoint(
      Script{{"[1] nodes", {"[1] OK"}},
             {"[2] monitor",
              {"[2] OK", frame_line(1, 1, '>', "705#05"), frame_line(2, 1, '>', "706#05"),
               frame_line(3, 0, '<', "605#4018100100000000"), frame_line(4, 1, '>', "185#01"),
               frame_line(5, 1, '>', "585#4318100178563412")}}});
  const auto run = run_cli({"dump", "--node", "5", "--kind", "sdo", "--kind", "heartbeat",
                            "--count", "3", "--endpoint", endpoint.address()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  const auto lines = lines_of(run.out);
  ASSERT_EQ(lines.size(), 3u) << run.out;
  EXPECT_THAT(lines[0], HasSubstr("heartbeat node 5"));
  EXPECT_THAT(lines[1], HasSubstr("SDO request node 5: upload 1018:01"));
  EXPECT_THAT(lines[2], HasSubstr("SDO response node 5: upload 1018:01 = 78 56 34 12"));
}

TEST(CliDump, ModuleFilterIsAskedOfTheEndpoint) {
  FakeEndpoint endpoint(
      Script{{"[1] nodes", {"[1] OK"}},
             {"[2] monitor module=2", {"[2] OK", frame_line(1, 2, '>', "080#")}}});
  const auto run =
      run_cli({"dump", "--module", "2", "--count", "1", "--endpoint", endpoint.address()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(run.out, HasSubstr("SYNC"));
}

TEST(CliDump, RawPrintsCandumpLines) {
  FakeEndpoint endpoint(
      Script{{"[1] monitor",
              {"[1] OK", frame_line(1, 1, '>', "705#05"), frame_line(2, 0, '<', "12345678#R")}}});
  const auto run = run_cli({"dump", "--raw", "--count", "2", "--endpoint", endpoint.address()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(lines_of(run.out), ElementsAre("(1700000000.000001) module1 705#05",
                                             "(1700000000.000002) surface 12345678#R"));
}

TEST(CliDump, ReportsDropsAndAClosedEndpoint) {
  FakeEndpoint endpoint(Script{{"[1] monitor",
                                {"[1] OK", frame_line(1, 1, '>', "705#05"), "DROPPED 17",
                                 frame_line(2, 1, '>', "705#05")}}});
  const auto run = run_cli({"dump", "--raw", "--endpoint", endpoint.address()});
  EXPECT_EQ(run.rc, exit_code::unreachable);  // the endpoint closed: no more frames will come
  EXPECT_EQ(lines_of(run.out).size(), 2u);
  EXPECT_THAT(run.err, HasSubstr("dropped 17 frames"));
  EXPECT_THAT(run.err, HasSubstr("closed the connection"));
}

TEST(CliDump, MonitorRefusedForTheRole) {
  FakeEndpoint endpoint(
      Script{{"[1] monitor", {"[1] ERROR:403 #Not permitted for role monitor."}}});
  EXPECT_EQ(run_cli({"dump", "--raw", "--endpoint", endpoint.address()}).rc,
            exit_code::unreachable);
}

class CliCapture : public ::testing::Test {
 protected:
  void TearDown() override { std::filesystem::remove(file_); }
  std::filesystem::path file_ = std::filesystem::temp_directory_path() /
                                ("canbridge-cli-capture-" + std::to_string(::getpid()));
  // NMT start, an SDO upload of 1018:01 and its answer, a heartbeat, an EMCY.
  std::vector<std::string> frames_ = {
      frame_line(1, 0, '<', "000#0105"), frame_line(2, 0, '<', "605#4018100100000000"),
      frame_line(3, 1, '>', "585#4318100178563412"), frame_line(4, 1, '>', "705#05"),
      frame_line(5, 1, '>', "085#1081110102030405")};
};

TEST_F(CliCapture, PcapThatTsharkDecodesAsCanopen) {
  std::vector<std::string> replies = {"[1] OK"};
  replies.insert(replies.end(), frames_.begin(), frames_.end());
  FakeEndpoint endpoint(Script{{"[1] monitor", replies}});
  const auto run =
      run_cli({"capture", "-w", file_.string(), "--count", "5", "--endpoint", endpoint.address()});
  ASSERT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(std::filesystem::file_size(file_), 24u + 5 * (16 + 16));

  const std::string tshark = find_tshark();
  ASSERT_FALSE(tshark.empty()) << "tshark is not on PATH: run tools/install-deps.sh";
  const auto decoded = run_tshark_canopen(tshark, file_.string());
  ASSERT_EQ(decoded.status, 0) << decoded.output;
  EXPECT_THAT(decoded.output, HasSubstr("Controller Area Network"));
  EXPECT_THAT(decoded.output, HasSubstr("Protocols in frame: can:canopen"));
  EXPECT_THAT(decoded.output, HasSubstr("OD main-index: Identity object (0x1018)"));
  EXPECT_THAT(decoded.output, HasSubstr("Start remote node"));
  EXPECT_THAT(decoded.output, HasSubstr("Initiate upload request"));
  EXPECT_THAT(decoded.output, HasSubstr("Operational"));
  EXPECT_THAT(decoded.output, HasSubstr("EMCY"));
}

TEST_F(CliCapture, CandumpLogReadsBack) {
  std::vector<std::string> replies = {"[1] OK"};
  replies.insert(replies.end(), frames_.begin(), frames_.end());
  FakeEndpoint endpoint(Script{{"[1] monitor", replies}});
  const auto run = run_cli(
      {"capture", "-w", file_.string(), "-l", "--count", "5", "--endpoint", endpoint.address()});
  ASSERT_EQ(run.rc, exit_code::ok) << run.err;
  std::ifstream in(file_);
  std::vector<can::CandumpRecord> records;
  EXPECT_EQ(can::read_candump_log(in, records), "");
  ASSERT_EQ(records.size(), 5u);
  EXPECT_EQ(records[0].interface, "surface");
  EXPECT_EQ(records[0].frame, can::Frame::standard(0x000, {0x01, 0x05}));
  EXPECT_EQ(records[4].interface, "module1");
  EXPECT_EQ(records[4].frame.timestamp, std::chrono::microseconds(1700000000000005LL));
}

}  // namespace
}  // namespace canbridge::test
