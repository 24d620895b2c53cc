// The client subcommands against the real CommandEndpoint (bridge/command_endpoint.*) in front of
// a RemoteAccess that answers at once: the client and the endpoint agree on the text protocol.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "app/cli_reply.hpp"
#include "bridge/command_endpoint.hpp"
#include "canopen/sdo_abort.hpp"
#include "tests/cli/cli_test_support.hpp"

namespace canbridge::test {
namespace {

namespace asio = boost::asio;
using ::testing::HasSubstr;
namespace exit_code = cli::exit_code;

// Answers every request on the executor, later than the call (as the surface does).
class AnsweringRemote : public bridge::RemoteAccess {
 public:
  explicit AnsweringRemote(asio::any_io_executor executor) : executor_(std::move(executor)) {}

  std::vector<bridge::NetworkInfo> networks() const override {
    return {{0, 0, "", false, true}, {2, 1, "gw-a", false, true}};
  }
  RequestId sdo(bridge::RemoteSdo request, Done done) override {
    sdo_requests.push_back(request);
    if (request.index == 0x6000) {
      return answer(std::move(done), {canopen::SdoAbort::no_object, {}, {}});
    }
    return answer(std::move(done), {{}, {0x78, 0x56, 0x34, 0x12}, {}});
  }
  RequestId nmt(bridge::RemoteTarget target, bridge::NmtCommand command, Done done) override {
    nmt_requests.emplace_back(target, command);
    return answer(std::move(done), {});
  }
  RequestId set_node_id(bridge::RemoteTarget, canopen::NodeId, Done done) override {
    return answer(std::move(done), {});
  }
  RequestId flash(bridge::RemoteTarget, std::vector<std::uint8_t> image,
                  std::function<void(const bridge::FlashProgress&)> progress, Done done) override {
    const auto total = image.size();
    asio::post(executor_, [progress, total] { progress({"download", total, total}); });
    return answer(std::move(done), {});
  }
  RequestId lss(bridge::NetworkNumber, std::string, std::vector<std::uint32_t>,
                Done done) override {
    return answer(std::move(done), {});
  }
  void cancel(RequestId) override {}
  void nodes(bridge::NetworkNumber,
             std::function<void(std::vector<bridge::NodeRow>, std::error_code)> done) override {
    bridge::NodeRow row;
    row.net = 2;
    row.module_id = 1;
    row.gateway = "gw-a";
    row.local_node = 5;
    row.surface_node = 21;
    row.profile = "cia301";
    row.nmt_state = 0x05;
    row.heartbeat_age = std::chrono::milliseconds(120);
    row.boot_count = 2;
    asio::post(executor_, [done, row] { done({row}, {}); });
  }
  std::uint64_t subscribe(std::function<void(const bridge::MonitorFrame&)> observer) override {
    observers_[++next_] = observer;
    asio::post(executor_, [observer] {
      observer({1700000000000001, 1, true, can::Frame::standard(0x705, {0x05})});
      observer({1700000000000002, 0, false, can::Frame::standard(0x000, {0x01, 0x15})});
    });
    return next_;
  }
  void unsubscribe(std::uint64_t id) override { observers_.erase(id); }

  std::vector<bridge::RemoteSdo> sdo_requests;
  std::vector<std::pair<bridge::RemoteTarget, bridge::NmtCommand>> nmt_requests;

 private:
  RequestId answer(Done done, bridge::RemoteOutcome outcome) {
    asio::post(executor_, [done = std::move(done), outcome] { done(outcome); });
    return ++next_;
  }
  asio::any_io_executor executor_;
  std::map<std::uint64_t, std::function<void(const bridge::MonitorFrame&)>> observers_;
  std::uint64_t next_ = 0;
};

class CliRealEndpoint : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("canbridge-cli-real-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    bridge::CommandEndpointOptions options;
    options.unix_socket = (dir_ / "surface.sock").string();
    endpoint_ = std::make_unique<bridge::CommandEndpoint>(ctx_.get_executor(), options, remote_);
    endpoint_->start();
    thread_ = std::thread([this] { ctx_.run(); });
  }
  void TearDown() override {
    asio::post(ctx_, [this] { endpoint_->stop(); });
    work_.reset();
    thread_.join();
    endpoint_.reset();
    std::filesystem::remove_all(dir_);
  }
  CliRun run(std::vector<std::string> args) {
    args.push_back("--endpoint");
    args.push_back((dir_ / "surface.sock").string());
    return run_cli(args);
  }

  asio::io_context ctx_;
  asio::executor_work_guard<asio::io_context::executor_type> work_{ctx_.get_executor()};
  AnsweringRemote remote_{ctx_.get_executor()};
  std::filesystem::path dir_;
  std::unique_ptr<bridge::CommandEndpoint> endpoint_;
  std::thread thread_;
};

TEST_F(CliRealEndpoint, SdoReadNmtAndAbort) {
  const auto read = run({"sdo", "read", "5", "1018", "1", "u32", "--net", "2"});
  EXPECT_EQ(read.rc, exit_code::ok) << read.err;
  EXPECT_EQ(read.out, "305419896\n");
  const auto abort = run({"sdo", "read", "5", "6000", "0", "--net", "2"});
  EXPECT_EQ(abort.rc, exit_code::abort);
  EXPECT_THAT(abort.err, HasSubstr("0x06020000"));
  const auto unknown = run({"sdo", "read", "5", "1018", "1", "--net", "9"});
  EXPECT_EQ(unknown.rc, exit_code::unknown) << unknown.err;
  const auto nmt = run({"nmt", "reset-comm", "all", "--net", "2"});
  EXPECT_EQ(nmt.rc, exit_code::ok) << nmt.err;
  ASSERT_EQ(remote_.nmt_requests.size(), 1u);
  EXPECT_EQ(remote_.nmt_requests[0].first.node, 0);
  ASSERT_GE(remote_.sdo_requests.size(), 1u);
  EXPECT_EQ(remote_.sdo_requests[0].index, 0x1018);
  EXPECT_EQ(remote_.sdo_requests[0].sub, 1);
}

TEST_F(CliRealEndpoint, NodesAndDump) {
  const auto nodes = run({"nodes"});
  EXPECT_EQ(nodes.rc, exit_code::ok) << nodes.err;
  EXPECT_THAT(nodes.out, HasSubstr("operational"));
  EXPECT_THAT(nodes.out, HasSubstr("gw-a"));
  const auto dump = run({"dump", "--count", "2"});
  EXPECT_EQ(dump.rc, exit_code::ok) << dump.err;
  EXPECT_THAT(dump.out, HasSubstr("module1 > 705#05"));
  EXPECT_THAT(dump.out, HasSubstr("heartbeat node 5 operational"));
  EXPECT_THAT(dump.out, HasSubstr("surface < 000#0115"));
  EXPECT_THAT(dump.out, HasSubstr("NMT start node 21"));
}

// cmd and the real endpoint agree on where each answer ends: a value, an abort, a multi-line
// help and a node table, each printed to its end before the next line goes.
TEST_F(CliRealEndpoint, CmdPrintsEachAnswerToItsEnd) {
  const auto r = run(
      {"cmd", "2 5 r 0x1018 1 u32", "[8] 2 5 r 0x6000 0", "help datatype", "nodes", "2 5 start"});
  EXPECT_EQ(r.rc, exit_code::abort) << r.err;  // the abort, the first error
  std::istringstream lines(r.out);
  std::vector<std::string> got;
  for (std::string line; std::getline(lines, line);) got.push_back(line);
  ASSERT_GE(got.size(), 4u) << r.out;
  EXPECT_EQ(got[0], "[1] 305419896");
  EXPECT_EQ(got[1], "[8] ERROR:0x06020000 #Object does not exist.");
  EXPECT_EQ(got[2], "Datatypes:");
  EXPECT_THAT(r.out, HasSubstr("\n[3] OK\n[4] node net=2 module=1 gateway=gw-a local=5"));
  EXPECT_TRUE(r.out.ends_with("\n[4] OK\n[5] OK\n")) << r.out;
  ASSERT_EQ(remote_.nmt_requests.size(), 1u);
}

TEST_F(CliRealEndpoint, FlashWithProgressAndSetNodeId) {
  const auto image = dir_ / "image.bin";
  std::ofstream(image, std::ios::binary) << std::string(4096, 'x');
  const auto flash = run({"flash", "5", image.string(), "--net", "2"});
  EXPECT_EQ(flash.rc, exit_code::ok) << flash.err;
  EXPECT_THAT(flash.out, HasSubstr("download: 4096/4096 bytes (100%)"));
  const auto rename = run({"set-node-id", "5", "9", "--net", "2"});
  EXPECT_EQ(rename.rc, exit_code::ok) << rename.err;
}

}  // namespace
}  // namespace canbridge::test
