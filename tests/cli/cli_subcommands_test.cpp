// Each request subcommand against a scripted endpoint: the exact line it sends, what it prints
// and its exit code, including the endpoint's errors and an endpoint that is missing or silent.
#include <arpa/inet.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "app/cli_reply.hpp"
#include "tests/cli/cli_test_support.hpp"
#include "tests/cli/fake_endpoint.hpp"

namespace canbridge::test {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
namespace exit_code = cli::exit_code;

std::vector<std::string> with_endpoint(std::vector<std::string> args, const FakeEndpoint& e) {
  args.push_back("--endpoint");
  args.push_back(e.address());
  return args;
}

TEST(CliNodes, PrintsTheNodeRowsAsATable) {
  FakeEndpoint endpoint(
      Script{{"[1] nodes",
              {"[1] node net=0 module=1 gateway=g1 local=5 surface=5 profile=cia301 "
               "kind=cia301 state=operational hb_age_ms=120 boot_count=1 emcy=-",
               "[1] node net=0 module=2 gateway=g1 local=3 surface=35 profile=qd "
               "kind=qd state=loader hb_age_ms=- boot_count=2 emcy=8130/11",
               "[1] OK"}}});
  const auto run = run_cli(with_endpoint({"nodes"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] nodes"));
  std::istringstream lines(run.out);
  std::string header, first, second;
  std::getline(lines, header);
  std::getline(lines, first);
  std::getline(lines, second);
  EXPECT_THAT(header, HasSubstr("MODULE"));
  EXPECT_THAT(header, HasSubstr("HB_AGE_MS"));
  EXPECT_THAT(first, HasSubstr("operational"));
  EXPECT_THAT(second, HasSubstr("8130/11"));
  // Aligned columns: STATE starts at the same offset in every line.
  EXPECT_EQ(first.find("operational"), header.find("STATE"));
  EXPECT_EQ(second.find("loader"), header.find("STATE"));
}

// The surface lists the nodes of a gateway that is down from its own table: the table, and a line
// naming the gateway; exit 0, as the surface knows them.
TEST(CliNodes, AGatewayThatIsDownIsNamedAndTheListSucceeds) {
  FakeEndpoint endpoint(
      Script{{"[1] nodes",
              {"[1] node net=2 module=1 gateway=g1 local=5 surface=5 profile=- kind=- "
               "state=lost hb_age_ms=- boot_count=1 emcy=-",
               "[1] gateway name=g1 state=down", "[1] OK"}}});
  const auto run = run_cli(with_endpoint({"nodes"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(run.out, HasSubstr("lost"));
  EXPECT_THAT(run.out, HasSubstr("gateway g1: down (its nodes are shown lost"));
}

TEST(CliNodes, NetOptionNamesTheNetwork) {
  FakeEndpoint endpoint(Script{{"[1] 3 nodes", {"[1] OK"}}});
  const auto run = run_cli(with_endpoint({"nodes", "--net", "3"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "no nodes\n");
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] 3 nodes"));
}

TEST(CliSdo, ReadSendsNetNodeIndexSubAndTypeAndPrintsTheValue) {
  FakeEndpoint endpoint(Script{{"[1] 0 5 r 0x1018 1 u32", {"[1] 305419896"}}});
  const auto run = run_cli(with_endpoint({"sdo", "read", "5", "1018", "1", "u32"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "305419896\n");
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] 0 5 r 0x1018 1 u32"));
}

TEST(CliSdo, ReadOnAnotherNetWithHexArgumentsAndNoType) {
  FakeEndpoint endpoint(Script{{"[1] 2 17 r 0x2F00 16", {"[1] 01 02 03"}}});
  const auto run =
      run_cli(with_endpoint({"sdo", "read", "0x11", "0x2f00", "0x10", "--net", "2"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "01 02 03\n");
}

TEST(CliSdo, ReadToAFileDecodesTheDomain) {
  const auto file = std::filesystem::temp_directory_path() / "canbridge-cli-read.bin";
  FakeEndpoint endpoint(Script{{"[1] 0 5 r 0x1F50 1 d", {"[1] AAEC/w=="}}});
  const auto run = run_cli(
      with_endpoint({"sdo", "read", "5", "1F50", "1", "d", "--file", file.string()}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  std::ifstream in(file, std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), {}};
  EXPECT_EQ(bytes, std::string("\x00\x01\x02\xFF", 4));
  std::filesystem::remove(file);
}

TEST(CliSdo, WriteQuotesAVisibleString) {
  FakeEndpoint endpoint(Script{{R"([1] 0 5 w 0x2000 0 vs "say ""hi""")", {"[1] OK"}}});
  const auto run =
      run_cli(with_endpoint({"sdo", "write", "5", "2000", "0", "vs", "say \"hi\""}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre(R"([1] 0 5 w 0x2000 0 vs "say ""hi""")"));
}

TEST(CliSdo, WriteAFileSendsItAsBase64) {
  const auto file = std::filesystem::temp_directory_path() / "canbridge-cli-write.bin";
  std::ofstream(file, std::ios::binary) << std::string("Man\0", 4);
  FakeEndpoint endpoint(Script{{"[1] 0 7 w 0x1F50 1 d TWFuAA==", {"[1] OK"}}});
  const auto run = run_cli(
      with_endpoint({"sdo", "write", "7", "0x1F50", "1", "d", "--file", file.string()}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] 0 7 w 0x1F50 1 d TWFuAA=="));
  std::filesystem::remove(file);
}

TEST(CliSdo, AbortExitsOneWithCodeAndText) {
  FakeEndpoint endpoint(
      Script{{"[1] 0 5 r 0x6000 0 u8", {"[1] ERROR:0x06020000 #Object does not exist."}}});
  const auto run = run_cli(with_endpoint({"sdo", "read", "5", "6000", "0", "u8"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::abort);
  EXPECT_THAT(run.err, HasSubstr("SDO abort 0x06020000: Object does not exist."));
  EXPECT_EQ(run.out, "");
}

TEST(CliSdo, AbortWithoutTextUsesTheAbortCategory) {
  FakeEndpoint endpoint(Script{{"[1] 0 5 r 0x6000 0", {"[1] ERROR:0x06010000"}}});
  const auto run = run_cli(with_endpoint({"sdo", "read", "5", "6000", "0"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::abort);
  EXPECT_THAT(run.err, HasSubstr("SDO abort: unsupported access to an object (0x06010000)"));
}

TEST(CliSdo, SdoTimeoutAbortExitsFour) {
  FakeEndpoint endpoint(
      Script{{"[1] 0 5 r 0x1000 0", {"[1] ERROR:0x05040000 #SDO protocol timed out."}}});
  EXPECT_EQ(run_cli(with_endpoint({"sdo", "read", "5", "1000", "0"}, endpoint)).rc,
            exit_code::timeout);
}

TEST(CliSdo, UnknownNodeAndNetExitThree) {
  {
    FakeEndpoint endpoint(Script{{"[1] 0 9 r 0x1000 0", {"[1] ERROR:107 #Unsupported node."}}});
    const auto run = run_cli(with_endpoint({"sdo", "read", "9", "1000", "0"}, endpoint));
    EXPECT_EQ(run.rc, exit_code::unknown);
    EXPECT_THAT(run.err, HasSubstr("error 107: Unsupported node."));
  }
  {
    FakeEndpoint endpoint(Script{{"[1] 7 9 r 0x1000 0", {"[1] ERROR:106 #Unsupported net."}}});
    EXPECT_EQ(run_cli(with_endpoint({"sdo", "read", "9", "1000", "0", "--net", "7"}, endpoint)).rc,
              exit_code::unknown);
  }
}

TEST(CliSdo, SilentEndpointTimesOutWithExitFour) {
  FakeEndpoint endpoint(Script{{"[1] 0 5 r 0x1000 0", {}}}, FakeEndpoint::Transport::unix_socket,
                        /*close_at_end=*/false);
  const auto run =
      run_cli(with_endpoint({"sdo", "read", "5", "1000", "0", "--timeout", "0.2"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::timeout);
  EXPECT_THAT(run.err, HasSubstr("no answer"));
}

TEST(CliSdo, EndpointClosingWithoutAnswerExitsFive) {
  FakeEndpoint endpoint(Script{{"[1] 0 5 r 0x1000 0", {}}});
  const auto run = run_cli(with_endpoint({"sdo", "read", "5", "1000", "0"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::unreachable);
  EXPECT_THAT(run.err, HasSubstr("closed the connection"));
}

TEST(CliEndpoint, MissingSocketExitsFive) {
  const auto run = run_cli({"nodes", "--endpoint", "/nonexistent/canbridge.sock"});
  EXPECT_EQ(run.rc, exit_code::unreachable);
  EXPECT_THAT(run.err,
              HasSubstr("cannot connect to the command endpoint /nonexistent/canbridge.sock"));
}

TEST(CliEndpoint, RefusedTcpPortExitsFive) {
  // A port bound but not listening: connecting to it is refused.
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), len), 0);
  ASSERT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
  const auto run =
      run_cli({"nodes", "--endpoint", "127.0.0.1:" + std::to_string(ntohs(addr.sin_port))});
  ::close(fd);
  EXPECT_EQ(run.rc, exit_code::unreachable);
  EXPECT_THAT(run.err, HasSubstr("refused"));
}

TEST(CliEndpoint, TcpSendsTheTokenFirst) {
  const auto token = std::filesystem::temp_directory_path() / "canbridge-cli.token";
  std::ofstream(token) << "s3cret\n";
  FakeEndpoint endpoint(Script{{"[1] auth s3cret", {"[1] OK"}}, {"[2] nodes", {"[2] OK"}}},
                        FakeEndpoint::Transport::tcp);
  const auto run = run_cli(with_endpoint({"nodes", "--token-file", token.string()}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] auth s3cret", "[2] nodes"));
  std::filesystem::remove(token);
}

TEST(CliEndpoint, TcpWithoutTokenIsRefusedWithExitFive) {
  FakeEndpoint endpoint(Script{{"[1] nodes", {"ERROR:401 #Authentication required."}}},
                        FakeEndpoint::Transport::tcp);
  const auto run = run_cli(with_endpoint({"nodes"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::unreachable);
  EXPECT_THAT(run.err, HasSubstr("401"));
}

TEST(CliEndpoint, MonitorRoleRefusalExitsFive) {
  FakeEndpoint endpoint(
      Script{{"[1] 0 5 start", {"[1] ERROR:403 #Not permitted for role monitor."}}});
  const auto run = run_cli(with_endpoint({"nmt", "start", "5"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::unreachable);
  EXPECT_THAT(run.err, HasSubstr("Not permitted for role monitor."));
}

TEST(CliEndpoint, ConfigFileNamesTheUnixSocket) {
  FakeEndpoint endpoint(Script{{"[1] nodes", {"[1] OK"}}});
  const auto config = std::filesystem::temp_directory_path() / "canbridge-cli-surface.yaml";
  std::ofstream(config) << "surface: {}\ncommand_endpoint:\n  unix_socket: " << endpoint.address()
                        << "\n  tcp_port: 0\n";
  const auto run = run_cli({"nodes", "-c", config.string()});
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  std::filesystem::remove(config);
}

TEST(CliEndpoint, UnreadableConfigIsAUsageError) {
  const auto run = run_cli({"nodes", "-c", "/nonexistent/surface.yaml"});
  EXPECT_EQ(run.rc, exit_code::usage);
  EXPECT_THAT(run.err, HasSubstr("/nonexistent/surface.yaml"));
}

TEST(CliUsage, BadArgumentsExitTwoBeforeConnecting) {
  // The endpoint does not exist: a subcommand that connected first would exit 5.
  const std::vector<std::vector<std::string>> bad = {
      {"sdo", "read", "200", "1000", "0"},
      {"sdo", "read", "5", "10000", "0"},
      {"sdo", "read", "5", "1000", "256"},
      {"sdo", "read", "5", "1000", "0", "float"},
      {"sdo", "write", "5", "1000", "0", "u8"},
      {"sdo", "write", "5", "1000", "0", "u8", "1", "--file", "/etc/hostname"},
      {"nmt", "restart", "5"},
      {"nmt", "start", "0"},
      {"set-node-id", "5", "128"},
      {"flash", "5", "/nonexistent/image.bin"},
      {"dump", "--kind", "bogus"},
      {"nodes", "--bogus"},
      {"sdo"},
      {"cmd", "4 start\n4 stop"},
      {"cmd", "# only a comment"},
      {"cmd", "4 start", "--net", "2"},
  };
  for (auto args : bad) {
    args.push_back("--endpoint");
    args.push_back("/nonexistent/canbridge.sock");
    const auto run = run_cli(args);
    EXPECT_EQ(run.rc, exit_code::usage)
        << args[0] << " " << (args.size() > 1 ? args[1] : "") << ": " << run.err;
    EXPECT_THAT(run.err, HasSubstr("canbridge: "));
  }
}

TEST(CliNmt, CommandsAndAllNodes) {
  FakeEndpoint endpoint(Script{{"[1] 0 0 reset comm", {"[1] OK"}}});
  EXPECT_EQ(run_cli(with_endpoint({"nmt", "reset-comm", "all"}, endpoint)).rc, exit_code::ok);
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] 0 0 reset comm"));
  FakeEndpoint second(Script{{"[1] 2 5 preop", {"[1] OK"}}});
  EXPECT_EQ(run_cli(with_endpoint({"nmt", "preop", "5", "--net", "2"}, second)).rc, exit_code::ok);
  EXPECT_THAT(second.received(), ElementsAre("[1] 2 5 preop"));
  FakeEndpoint third(Script{{"[1] 0 5 reset node", {"[1] OK"}}});
  EXPECT_EQ(run_cli(with_endpoint({"nmt", "reset", "5"}, third)).rc, exit_code::ok);
  EXPECT_THAT(third.received(), ElementsAre("[1] 0 5 reset node"));
}

TEST(CliSetNodeId, SendsTheRenameReportsTheSurfaceIdAndNoBootUp) {
  // On net 0 the new id is a local one; the node keeps surface id 5, which the endpoint answers.
  FakeEndpoint endpoint(Script{{"[1] 0 5 set node_id 9", {"[1] 5"}}});
  const auto run = run_cli(with_endpoint({"set-node-id", "5", "9"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_EQ(run.out, "node 5 renamed to local id 9; the surface addresses it as node 5\n");
  FakeEndpoint on_net(Script{{"[1] 3 3 set node_id 4", {"[1] 8"}}});
  const auto moved = run_cli(with_endpoint({"set-node-id", "--net", "3", "3", "4"}, on_net));
  EXPECT_EQ(moved.out, "node 3 of net 3 renamed to 4; the surface addresses it as node 8\n");
  FakeEndpoint unmapped(Script{{"[1] 3 3 set node_id 4", {"[1] -"}}});
  EXPECT_THAT(run_cli(with_endpoint({"set-node-id", "--net", "3", "3", "4"}, unmapped)).out,
              HasSubstr("no surface id"));
  FakeEndpoint older(Script{{"[1] 0 5 set node_id 9", {"[1] OK"}}});
  EXPECT_THAT(run_cli(with_endpoint({"set-node-id", "5", "9"}, older)).out,
              HasSubstr("not reported"));
  FakeEndpoint failing(
      Script{{"[1] 0 5 set node_id 9", {"[1] ERROR:0x05040000 #no boot-up on new id"}}});
  const auto failed = run_cli(with_endpoint({"set-node-id", "5", "9"}, failing));
  EXPECT_EQ(failed.rc, exit_code::timeout);
  EXPECT_THAT(failed.err, HasSubstr("no boot-up on new id"));
}

// `cmd`: raw 309-3 lines as cocomm sends them. A line without a sequence gets "[<its place>] ",
// one with a sequence goes as written; every answer line is printed as it came (a multi-line
// answer to its end), one request at a time.
TEST(CliCmd, SendsEachLineAndPrintsItsAnswerAsItCame) {
  FakeEndpoint endpoint(Script{
      {"[1] 4 read 0x1017 0 u16", {"[1] 1000"}},
      {"[7] 4 start", {"[7] OK"}},
      {"[3] nodes",
       {"[3] node net=2 module=1 gateway=g local=4 surface=4 profile=- kind=- state=lost "
        "hb_age_ms=- boot_count=0 emcy=-",
        "[3] gateway name=g state=down", "[3] OK"}},
      {"[4] help datatype", {"Datatypes:\nb                  # Boolean.\n[4] OK"}},
  });
  const auto run = run_cli(with_endpoint(
      {"cmd", "4 read 0x1017 0 u16", "[7] 4 start", "nodes", "help datatype"}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[1] 4 read 0x1017 0 u16", "[7] 4 start",
                                               "[3] nodes", "[4] help datatype"));
  EXPECT_EQ(run.out,
            "[1] 1000\n[7] OK\n"
            "[3] node net=2 module=1 gateway=g local=4 surface=4 profile=- kind=- state=lost "
            "hb_age_ms=- boot_count=0 emcy=-\n[3] gateway name=g state=down\n[3] OK\n"
            "Datatypes:\nb                  # Boolean.\n[4] OK\n");
  EXPECT_EQ(run.err, "");
}

// An ERROR answer is printed like any other and the next line still goes; the exit status is
// the first error's, by the conventions of the other commands (108: 6, an SDO abort: 1). A line
// with a malformed sequence is refused by the endpoint without a sequence.
TEST(CliCmd, TheFirstErrorAnswerGivesTheExitStatus) {
  FakeEndpoint endpoint(Script{
      {"[1] 4 w 0x2000 0 u8 1", {"[1] ERROR:108 #Outcome unknown, may have been executed."}},
      {"[2] 4 r 0x6000 0 u8", {"[2] ERROR:0x06020000 #Object does not exist."}},
      {"[x] 4 start", {"ERROR:101 #Syntax error."}},
      {"[4] 4 r 0x1017 0 u16", {"[4] 0"}},
  });
  const auto run = run_cli(with_endpoint(
      {"cmd", "4 w 0x2000 0 u8 1", "4 r 0x6000 0 u8", "[x] 4 start", "4 r 0x1017 0 u16"},
      endpoint));
  EXPECT_EQ(run.rc, exit_code::outcome_unknown);
  EXPECT_EQ(run.out,
            "[1] ERROR:108 #Outcome unknown, may have been executed.\n"
            "[2] ERROR:0x06020000 #Object does not exist.\nERROR:101 #Syntax error.\n[4] 0\n");
  FakeEndpoint abort(
      Script{{"[1] 4 r 0x6000 0 u8", {"[1] ERROR:0x06020000 #Object does not exist."}},
             {"[2] 4 r 0x1017 0 u16", {"[2] 0"}}});
  EXPECT_EQ(run_cli(with_endpoint({"cmd", "4 r 0x6000 0 u8", "4 r 0x1017 0 u16"}, abort)).rc,
            exit_code::abort);
}

// Without lines the requests come from standard input, numbered by their line there; blank and
// comment lines (cocomm's files have them) are not sent, a CR before the LF is dropped.
TEST(CliCmd, WithoutLinesReadsStandardInput) {
  FakeEndpoint endpoint(Script{{"[3] 4 r 0x1017 0 u16", {"[3] 500"}}, {"[9] 4 stop", {"[9] OK"}}});
  const auto run = run_cli_with_input(with_endpoint({"cmd"}, endpoint),
                                      "# set up\n\n4 r 0x1017 0 u16\r\n[9] 4 stop\n");
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre("[3] 4 r 0x1017 0 u16", "[9] 4 stop"));
  EXPECT_EQ(run.out, "[3] 500\n[9] OK\n");
}

TEST(CliCmd, ASilentOrClosingEndpointEndsTheRunWithItsCode) {
  FakeEndpoint silent(Script{{"[1] 4 start", {}}}, FakeEndpoint::Transport::unix_socket,
                      /*close_at_end=*/false);
  const auto timed_out =
      run_cli(with_endpoint({"cmd", "4 start", "4 stop", "--timeout", "0.2"}, silent));
  EXPECT_EQ(timed_out.rc, exit_code::timeout);
  EXPECT_THAT(timed_out.err, HasSubstr("no answer"));
  FakeEndpoint closing(Script{{"[1] 4 start", {}}});
  EXPECT_EQ(run_cli(with_endpoint({"cmd", "4 start", "4 stop"}, closing)).rc,
            exit_code::unreachable);
}

class CliFlash : public ::testing::Test {
 protected:
  void SetUp() override { std::ofstream(image_, std::ios::binary) << std::string(1000, 'x'); }
  void TearDown() override { std::filesystem::remove(image_); }
  std::filesystem::path image_ = std::filesystem::temp_directory_path() / "canbridge-cli-image.bin";
  std::string request() const { return "[1] 0 5 flash " + image_.string(); }
};

TEST_F(CliFlash, PlainProgressLinesOnANonTerminal) {
  std::vector<std::string> replies = {"[1] PROGRESS reset 0 0", "[1] PROGRESS loader 0 0"};
  for (int done = 0; done <= 1000; done += 50) {
    replies.push_back("[1] PROGRESS download " + std::to_string(done) + " 1000");
  }
  replies.push_back("[1] PROGRESS verify 1000 1000");
  replies.push_back("[1] OK");
  FakeEndpoint endpoint(Script{{request(), replies}});
  const auto run = run_cli(with_endpoint({"flash", "5", image_.string()}, endpoint));
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(endpoint.received(), ElementsAre(request()));
  EXPECT_EQ(run.out.find('\r'), std::string::npos);
  EXPECT_EQ(run.out.find('\x1b'), std::string::npos);
  // One line per step, and per tenth of the download (21 updates -> 11 lines).
  std::size_t download_lines = 0;
  std::istringstream lines(run.out);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("download: ", 0) == 0) ++download_lines;
  }
  EXPECT_EQ(download_lines, 11u) << run.out;
  EXPECT_THAT(run.out, HasSubstr("download: 500/1000 bytes (50%)"));
  EXPECT_THAT(run.out, HasSubstr("verify: 1000/1000 bytes (100%)"));
  EXPECT_THAT(run.out, HasSubstr("flashed "));
}

TEST_F(CliFlash, BarOnATerminal) {
  FakeEndpoint endpoint(
      Script{{request(),
              {"[1] PROGRESS download 500 1000", "[1] PROGRESS download 1000 1000", "[1] OK"}}});
  const auto run = run_cli(with_endpoint({"flash", "5", image_.string()}, endpoint), true);
  EXPECT_EQ(run.rc, exit_code::ok) << run.err;
  EXPECT_THAT(run.out, HasSubstr("\r[##########..........]  50%"));
  EXPECT_THAT(run.out, HasSubstr("\r[####################] 100%"));
}

TEST_F(CliFlash, PathWithACommentSignIsRefusedBeforeConnecting) {
  const auto hashed = std::filesystem::temp_directory_path() / "canbridge#image.bin";
  std::ofstream(hashed) << "x";
  const auto run = run_cli({"flash", "5", hashed.string(), "--endpoint", "/nonexistent/e.sock"});
  std::filesystem::remove(hashed);
  EXPECT_EQ(run.rc, exit_code::usage);
  EXPECT_THAT(run.err, HasSubstr("contains '#'"));
}

TEST_F(CliFlash, FailedStepExitsOneAndNamesIt) {
  FakeEndpoint endpoint(Script{{request(),
                                {"[1] PROGRESS download 1000 1000",
                                 "[1] ERROR:0x08000020 #verify: 1F56h:01 CRC does not match"}}});
  const auto run = run_cli(with_endpoint({"flash", "5", image_.string()}, endpoint));
  EXPECT_EQ(run.rc, exit_code::abort);
  EXPECT_THAT(run.err, HasSubstr("0x08000020: verify: 1F56h:01 CRC does not match"));
}

}  // namespace
}  // namespace canbridge::test
