// The surface's CiA 309-3 command endpoint on real sockets (a Unix socket in a temporary
// directory, loopback TCP), driven by a plain socket client that writes the text protocol and
// reads raw bytes, in front of a scripted RemoteAccess that records every call and is completed
// by the test.
#include "bridge/command_endpoint.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <algorithm>
#include <boost/asio/io_context.hpp>
#include <chrono>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "canopen/ascii_command.hpp"
#include "canopen/sdo_abort.hpp"
#include "tests/support/event_loop.hpp"
#include "tests/support/temp_key_dir.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;
using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

// Records every request; the test completes them (always later than the call, as the real one).
class ScriptedRemote : public RemoteAccess {
 public:
  struct Call {
    std::string kind;  // sdo, nmt, set_node_id, flash, lss
    RequestId id = 0;
    RemoteSdo sdo;
    RemoteTarget target;
    NmtCommand nmt = NmtCommand::start;
    canopen::NodeId new_node = 0;
    Bytes image;
    std::function<void(const FlashProgress&)> progress;
    NetworkNumber net = 0;
    std::string lss;
    std::vector<std::uint32_t> args;
    Done done;
  };

  std::vector<NetworkInfo> networks() const override { return nets; }
  RequestId sdo(RemoteSdo request, Done done) override {
    Call call = next("sdo", std::move(done));
    call.target = request.target;
    call.sdo = std::move(request);
    return push(std::move(call));
  }
  RequestId nmt(RemoteTarget target, NmtCommand command, Done done) override {
    Call call = next("nmt", std::move(done));
    call.target = target;
    call.nmt = command;
    return push(std::move(call));
  }
  RequestId set_node_id(RemoteTarget target, canopen::NodeId new_node, Done done) override {
    Call call = next("set_node_id", std::move(done));
    call.target = target;
    call.new_node = new_node;
    return push(std::move(call));
  }
  RequestId flash(RemoteTarget target, std::vector<std::uint8_t> image,
                  std::function<void(const FlashProgress&)> progress, Done done) override {
    Call call = next("flash", std::move(done));
    call.target = target;
    call.image = std::move(image);
    call.progress = std::move(progress);
    return push(std::move(call));
  }
  RequestId lss(NetworkNumber net, std::string command, std::vector<std::uint32_t> args,
                Done done) override {
    Call call = next("lss", std::move(done));
    call.net = net;
    call.lss = std::move(command);
    call.args = std::move(args);
    return push(std::move(call));
  }
  void cancel(RequestId id) override { cancelled.push_back(id); }
  void nodes(NetworkNumber net,
             std::function<void(std::vector<NodeRow>, std::error_code)> done) override {
    nodes_asked.push_back(net);
    nodes_done = std::move(done);
  }
  std::uint64_t subscribe(std::function<void(const MonitorFrame&)> observer) override {
    observers[++next_subscription] = std::move(observer);
    return next_subscription;
  }
  void unsubscribe(std::uint64_t id) override { observers.erase(id); }

  // Completes call `i` (once).
  void complete(std::size_t i, RemoteOutcome outcome) {
    ASSERT_LT(i, calls.size());
    ASSERT_TRUE(calls[i].done) << "completed twice";
    auto done = std::move(calls[i].done);
    calls[i].done = nullptr;
    done(std::move(outcome));
  }
  void complete_ok(std::size_t i, Bytes data = {}) { complete(i, RemoteOutcome{{}, data, {}}); }
  void emit(const MonitorFrame& frame) {
    for (auto& [id, observer] : std::map(observers)) observer(frame);
  }

  std::vector<NetworkInfo> nets{
      {0, 0, "", false, true},
      {2, 1, "gw-a", true, true},  // module 1, LSS
      {3, 2, "gw-b", false, true},
  };
  std::vector<Call> calls;
  std::vector<RequestId> cancelled;
  std::vector<NetworkNumber> nodes_asked;
  std::function<void(std::vector<NodeRow>, std::error_code)> nodes_done;
  std::map<std::uint64_t, std::function<void(const MonitorFrame&)>> observers;

 private:
  Call next(std::string kind, Done done) {
    Call call;
    call.kind = std::move(kind);
    call.id = 1000 + calls.size();
    call.done = std::move(done);
    return call;
  }
  RequestId push(Call call) {
    calls.push_back(std::move(call));
    return calls.back().id;
  }
  std::uint64_t next_subscription = 0;
};

// A client that knows nothing of canbridge: a socket, bytes out, bytes in.
class RawClient {
 public:
  static std::unique_ptr<RawClient> unix_socket(const std::string& path) {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, path.c_str(), sizeof address.sun_path - 1);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
      ::close(fd);
      throw std::runtime_error("connect " + path + ": " + std::strerror(errno));
    }
    return std::unique_ptr<RawClient>(new RawClient(fd));
  }
  static std::unique_ptr<RawClient> tcp(std::uint16_t port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
      ::close(fd);
      throw std::runtime_error(std::string("connect tcp: ") + std::strerror(errno));
    }
    return std::unique_ptr<RawClient>(new RawClient(fd));
  }
  ~RawClient() { close(); }
  RawClient(const RawClient&) = delete;
  RawClient& operator=(const RawClient&) = delete;

  void send(std::string_view bytes) {
    while (!bytes.empty()) {
      const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
      if (n <= 0) throw std::runtime_error(std::string("send: ") + std::strerror(errno));
      bytes.remove_prefix(static_cast<std::size_t>(n));
    }
  }
  // Takes what has arrived, without waiting.
  void pump() {
    char buf[4096];
    for (;;) {
      const ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
      if (n > 0) {
        received_.append(buf, static_cast<std::size_t>(n));
      } else {
        if (n == 0) eof_ = true;
        if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) eof_ = true;
        return;
      }
    }
  }
  // The complete lines received, each without its CR LF.
  std::vector<std::string> lines() const {
    std::vector<std::string> out;
    std::size_t start = 0;
    for (std::size_t end; (end = received_.find("\r\n", start)) != std::string::npos;
         start = end + 2) {
      out.push_back(received_.substr(start, end - start));
    }
    return out;
  }
  // Closes the sending side only, as `printf ... | socat` does at the end of its input.
  void shutdown_send() { ::shutdown(fd_, SHUT_WR); }
  const std::string& received() const { return received_; }
  bool eof() const { return eof_; }
  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

 private:
  explicit RawClient(int fd) : fd_(fd) {}
  int fd_;
  std::string received_;
  bool eof_ = false;
};

std::uint16_t free_tcp_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address);
  socklen_t len = sizeof address;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &len);
  ::close(fd);
  return ntohs(address.sin_port);
}

class CommandEndpointTest : public ::testing::Test {
 protected:
  CommandEndpointOptions options() {
    CommandEndpointOptions o;
    o.unix_socket = dir.path() + "/surface.sock";
    return o;
  }
  void start(CommandEndpointOptions o) {
    endpoint = std::make_unique<CommandEndpoint>(io.get_executor(), std::move(o), remote);
    endpoint->start();
  }
  std::unique_ptr<RawClient> connect() {
    return RawClient::unix_socket(dir.path() + "/surface.sock");
  }

  bool until(const std::function<bool()>& done) { return test::run_until(io, done, 5000ms); }
  // Waits until the client has `n` complete lines; returns them all.
  std::vector<std::string> lines(RawClient& client, std::size_t n) {
    EXPECT_TRUE(until([&] {
      client.pump();
      return client.lines().size() >= n;
    })) << "got: "
        << client.received();
    return client.lines();
  }
  std::string line(RawClient& client, std::size_t i) {
    const auto all = lines(client, i + 1);
    return all.size() > i ? all[i] : std::string();
  }
  bool closed_by_endpoint(RawClient& client) {
    return until([&] {
      client.pump();
      return client.eof();
    });
  }
  std::size_t calls_soon(std::size_t n) {
    until([&] { return remote.calls.size() >= n; });
    return remote.calls.size();
  }
  // Writes one byte per write and lets the endpoint read each one alone.
  void send_bytewise(RawClient& client, std::string_view text) {
    for (char c : text) {
      client.send(std::string_view(&c, 1));
      io.restart();
      io.poll();
    }
  }
  void TearDown() override {
    if (endpoint) {
      endpoint->stop();
      until([&] { return endpoint->counters().sessions == 0; });
      endpoint.reset();
      io.restart();
      io.poll();
    }
  }

  ScriptedRemote remote;  // outlives the io_context and the endpoint
  asio::io_context io;
  test::TempKeyDir dir;
  std::unique_ptr<CommandEndpoint> endpoint;
};

TEST_F(CommandEndpointTest, ReadAndWriteOneBytePerWrite) {
  start(options());
  auto client = connect();
  send_bytewise(*client, "[1] 5 read 0x1018 1 u32\n");
  ASSERT_EQ(calls_soon(1), 1u);
  const auto& read = remote.calls[0];
  EXPECT_EQ(read.kind, "sdo");
  EXPECT_EQ(read.sdo.target.net, 0u);
  EXPECT_EQ(read.sdo.target.node, 5);
  EXPECT_EQ(read.sdo.index, 0x1018);
  EXPECT_EQ(read.sdo.sub, 1);
  EXPECT_TRUE(read.sdo.upload);
  EXPECT_EQ(read.sdo.timeout, 500ms);  // CANopenNode's gateway's default
  EXPECT_EQ(read.sdo.block_size, 0);
  remote.complete_ok(0, {0x78, 0x56, 0x34, 0x12});
  EXPECT_EQ(line(*client, 0), "[1] 305419896");
  EXPECT_EQ(client->received(), "[1] 305419896\r\n");  // CR LF, nothing else

  send_bytewise(*client, "[2] 2 7 w 0x2000 0 u16 0x1234\r\n");
  ASSERT_EQ(calls_soon(2), 2u);
  EXPECT_FALSE(remote.calls[1].sdo.upload);
  EXPECT_EQ(remote.calls[1].sdo.target.net, 2u);
  EXPECT_EQ(remote.calls[1].sdo.target.node, 7);
  EXPECT_EQ(remote.calls[1].sdo.data, (Bytes{0x34, 0x12}));
  remote.complete_ok(1);
  EXPECT_EQ(line(*client, 1), "[2] OK");
}

TEST_F(CommandEndpointTest, SessionSettingsDefaultsAndErrors) {
  start(options());
  auto client = connect();
  client->send("r 0x1000 0\n");  // no default node, no sequence
  EXPECT_EQ(line(*client, 0), "ERROR:105 #No default node set.");
  client->send("[2] set node 9\n[3] set sdo_timeout 250\n[4] set sdo_block 1\n[5] r 0x1000 0\n");
  EXPECT_EQ(line(*client, 3), "[4] OK");
  ASSERT_EQ(calls_soon(1), 1u);
  EXPECT_EQ(remote.calls[0].sdo.target.node, 9);
  EXPECT_EQ(remote.calls[0].sdo.timeout, 250ms);
  EXPECT_EQ(remote.calls[0].sdo.block_size, 127);
  remote.complete_ok(0, {0x92, 0x01, 0x08, 0x00});  // no datatype: hex
  EXPECT_EQ(line(*client, 4), "[5] 92 01 08 00");

  client->send("[6] r 0x6000 1 u8\n");
  ASSERT_EQ(calls_soon(2), 2u);
  remote.complete(1, RemoteOutcome{canopen::abort_error(0x06020000), {}, {}});
  EXPECT_EQ(line(*client, 5), "[6] ERROR:0x06020000 #Object does not exist.");

  client->send("[7] 9 5 r 0x1000 0\n[8] set network 9\n[9] 2 set network 3\n");
  EXPECT_EQ(line(*client, 6), "[7] ERROR:106 #Unsupported net. net 9");
  EXPECT_EQ(line(*client, 7), "[8] ERROR:106 #Unsupported net. net 9");
  EXPECT_EQ(line(*client, 8), "[9] OK");
  client->send("[10] r 0x1000 0\n[11] r 0x1000 0\n[12] r 0x1000 0\n[13] r 0x1000 0\n");
  ASSERT_EQ(calls_soon(6), 6u);
  EXPECT_EQ(remote.calls[2].sdo.target.net, 3u);  // the new default net
  remote.complete(
      2, RemoteOutcome{
             std::make_error_code(std::errc::no_such_device_or_address), {}, "no node 9 on net 3"});
  remote.complete(3, RemoteOutcome{std::make_error_code(std::errc::host_unreachable),
                                   {},
                                   "gateway gw-b is not connected"});
  remote.complete(4, RemoteOutcome{std::make_error_code(std::errc::timed_out), {}, {}});
  remote.complete(5, RemoteOutcome{canopen::abort_error(0x08000020), {}, "verify"});
  EXPECT_EQ(line(*client, 9), "[10] ERROR:107 #Unsupported node. no node 9 on net 3");
  EXPECT_EQ(line(*client, 10), "[11] ERROR:201 #Lost connection. gateway gw-b is not connected");
  EXPECT_EQ(line(*client, 11).rfind("[12] ERROR:103 #Time-out.", 0), 0u);
  EXPECT_EQ(line(*client, 12),
            "[13] ERROR:0x08000020 #Data cannot be transferred or stored to application. verify");
  // A write whose answer can never come (its gateway died): its own answer, not a time-out.
  client->send("[14] w 0x6000 1 u8 1\n");
  ASSERT_EQ(calls_soon(7), 7u);
  remote.complete(6, RemoteOutcome{make_error_code(RemoteEnd::outcome_unknown), {}, "read back"});
  EXPECT_EQ(line(*client, 13),
            "[14] ERROR:108 #Outcome unknown, may have been executed. read back");
  const auto counters = endpoint->counters();
  EXPECT_EQ(counters.commands, 14u);
  EXPECT_EQ(counters.errors, 9u);
}

TEST_F(CommandEndpointTest, NmtSetNodeIdHelpAndLss) {
  start(options());
  auto client = connect();
  client->send("[1] 0 reset comm\n[2] 2 4 preop\n[3] 2 4 set node_id 9\n");
  ASSERT_EQ(calls_soon(3), 3u);
  EXPECT_EQ(remote.calls[0].kind, "nmt");
  EXPECT_EQ(remote.calls[0].target.node, 0);  // every node
  EXPECT_EQ(remote.calls[0].nmt, NmtCommand::reset_communication);
  EXPECT_EQ(remote.calls[1].nmt, NmtCommand::preoperational);
  EXPECT_EQ(remote.calls[1].target.net, 2u);
  EXPECT_EQ(remote.calls[2].kind, "set_node_id");
  EXPECT_EQ(remote.calls[2].new_node, 9);
  for (std::size_t i = 0; i < 2; ++i) remote.complete_ok(i);
  remote.complete_ok(2, {21});  // the surface id the renamed node has now
  EXPECT_EQ(line(*client, 2), "[3] 21");
  client->send("[31] 2 9 set node_id 10\n[32] 2 10 set node_id 11\n");
  ASSERT_EQ(calls_soon(5), 5u);
  remote.complete_ok(3, {0});  // no surface id
  remote.complete_ok(4);       // a gateway that does not say
  EXPECT_EQ(line(*client, 3), "[31] -");
  EXPECT_EQ(line(*client, 4), "[32] OK");

  client->send("[4] help datatype\n");
  // One answer, one CR LF: its lines are separated by LF alone (as the reference gateway's help),
  // so a client that prints an answer per CR LF (cocomm) prints all of it.
  const auto help = lines(*client, 6);
  ASSERT_EQ(help.size(), 6u);
  EXPECT_EQ(help[5].rfind("Datatypes:\n", 0), 0u) << help[5];
  EXPECT_TRUE(help[5].ends_with("\n[4] OK")) << help[5];
  EXPECT_EQ(std::count(help[5].begin(), help[5].end(), '\n'),
            static_cast<long>(canopen::ascii_help("datatype").size()));

  const std::size_t seen = help.size();
  client->send("[5] 3 lss_store\n[6] 2 lss_get_node\n[7] 2 lss_inquire_addr\n[8] lss_store\n");
  EXPECT_EQ(line(*client, seen), "[5] ERROR:100 #Request not supported. no LSS on net 3");
  ASSERT_EQ(calls_soon(7), 7u);
  EXPECT_EQ(remote.calls[5].lss, "lss_get_node");
  EXPECT_EQ(remote.calls[5].net, 2u);
  remote.complete_ok(5, {0x05});
  remote.complete_ok(6, {1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 0xEF, 0xBE, 0, 0});
  EXPECT_EQ(line(*client, seen + 1), "[6] 0x05");
  EXPECT_EQ(line(*client, seen + 2), "[7] 0x00000001 0x00000002 0x00000003 0x0000BEEF");
  // Net 0 (the surface's network) has no LSS of its own.
  EXPECT_EQ(line(*client, seen + 3), "[8] ERROR:100 #Request not supported. no LSS on net 0");
}

TEST_F(CommandEndpointTest, NodesLinesAsDocumented) {
  start(options());
  auto client = connect();
  client->send("[3] 2 nodes\n");
  ASSERT_TRUE(until([&] { return remote.nodes_done != nullptr; }));
  EXPECT_EQ(remote.nodes_asked, std::vector<NetworkNumber>{2});
  NodeRow a;
  a.net = 2;
  a.module_id = 1;
  a.gateway = "gw-a";
  a.local_node = 5;
  a.surface_node = 21;
  a.profile = "drive";
  a.kind = "motor";
  a.nmt_state = 0x05;
  a.heartbeat_age = 120ms;
  a.boot_count = 2;
  a.last_emcy_code = 0x8130;
  a.last_emcy_register = 0x11;
  NodeRow b;
  b.net = 2;
  b.module_id = 1;
  b.gateway = "gw-a";
  b.local_node = 6;
  b.profile = "io";
  b.lost = true;
  remote.nodes_done({a, b}, {});
  // One answer, one CR LF (as help): the rows end in LF alone, so that cocomm prints them all.
  EXPECT_EQ(line(*client, 0),
            "[3] node net=2 module=1 gateway=gw-a local=5 surface=21 profile=drive kind=motor "
            "state=operational hb_age_ms=120 boot_count=2 emcy=8130/11\n"
            "[3] node net=2 module=1 gateway=gw-a local=6 surface=- profile=io kind=- state=lost "
            "hb_age_ms=- boot_count=0 emcy=-\n"
            "[3] OK");
}

// A gateway that is down: its rows (the surface's own, lost) are listed, then one line names the
// gateway and its state, and the answer is OK. Only the gateways of the network asked for.
TEST_F(CommandEndpointTest, NodesNameAGatewayThatIsDown) {
  remote.nets[2].connected = false;  // gw-b, net 3
  start(options());
  auto client = connect();
  client->send("[4] nodes\n");
  ASSERT_TRUE(until([&] { return remote.nodes_done != nullptr; }));
  NodeRow lost;
  lost.net = 3;
  lost.module_id = 2;
  lost.gateway = "gw-b";
  lost.local_node = 1;
  lost.surface_node = 5;
  lost.lost = true;
  remote.nodes_done({lost}, {});
  EXPECT_EQ(line(*client, 0),
            "[4] node net=3 module=2 gateway=gw-b local=1 surface=5 profile=- kind=- "
            "state=lost hb_age_ms=- boot_count=0 emcy=-\n"
            "[4] gateway name=gw-b state=down\n"
            "[4] OK");
  remote.nodes_done = nullptr;
  client->send("[5] 2 nodes\n");
  ASSERT_TRUE(until([&] { return remote.nodes_done != nullptr; }));
  remote.nodes_done({}, {});
  EXPECT_EQ(line(*client, 1), "[5] OK");
}

TEST_F(CommandEndpointTest, FlashReadsTheFileAndReportsProgress) {
  start(options());
  auto client = connect();
  const std::string image = dir.file("fw.bin", "\x01\x02\x03image", 0600);
  client->send("[1] 2 5 flash " + image + "\n");
  ASSERT_EQ(calls_soon(1), 1u);
  EXPECT_EQ(remote.calls[0].kind, "flash");
  EXPECT_EQ(remote.calls[0].image, (Bytes{1, 2, 3, 'i', 'm', 'a', 'g', 'e'}));
  remote.calls[0].progress(FlashProgress{"download", 4, 8});
  EXPECT_EQ(line(*client, 0), "[1] PROGRESS download 4 8");
  remote.calls[0].progress(FlashProgress{"verify", 8, 8});
  remote.complete_ok(0);
  EXPECT_EQ(line(*client, 2), "[1] OK");
  EXPECT_EQ(lines(*client, 3)[1], "[1] PROGRESS verify 8 8");

  client->send("[2] 5 flash " + dir.path() + "/missing.bin\n[3] 5 flash " + dir.path() + "\n");
  EXPECT_EQ(line(*client, 3)
                .rfind("[2] ERROR:102 #Request not processed due to internal state. "
                       "flash: cannot read ",
                       0),
            0u);
  EXPECT_NE(line(*client, 3).find("No such file"), std::string::npos);
  EXPECT_NE(line(*client, 4).find("is not a regular file"), std::string::npos);
  EXPECT_EQ(remote.calls.size(), 1u);
}

TEST_F(CommandEndpointTest, PipelinedCommandsAreAnsweredInOrder) {
  start(options());
  auto client = connect();
  client->send("[1] 5 r 0x1000 0 u8\n[2] 6 r 0x1000 0 u8\n# a comment\n\n[3] 7 r 0x1000 0 u8\n");
  ASSERT_EQ(calls_soon(3), 3u);
  remote.complete_ok(2, {3});
  remote.complete_ok(1, {2});
  for (int i = 0; i < 20; ++i) {  // everything ready runs; nothing may be written yet
    io.restart();
    io.poll();
  }
  client->pump();
  EXPECT_EQ(client->received(), "") << "answered before the first request";
  remote.complete_ok(0, {1});
  // The comment and the blank line get their empty answers in their places.
  EXPECT_EQ(lines(*client, 5), (std::vector<std::string>{"[1] 1", "[2] 2", "", "", "[3] 3"}));
}

TEST_F(CommandEndpointTest, TwoClientsOneNodeEachGetsItsOwnAnswer) {
  start(options());
  auto a = connect();
  auto b = connect();
  a->send("[1] 5 r 0x1000 0 u8\n");
  ASSERT_EQ(calls_soon(1), 1u);
  // B's request to the same node reaches the surface while A's is pending: the per-node queue is
  // the surface's (RemoteAccess), not a lock in the endpoint.
  b->send("[1] 5 r 0x1001 0 u8\n");
  ASSERT_EQ(calls_soon(2), 2u);
  EXPECT_EQ(remote.calls[1].sdo.index, 0x1001);
  remote.complete_ok(0, {10});
  EXPECT_EQ(line(*a, 0), "[1] 10");
  remote.complete_ok(1, {11});
  EXPECT_EQ(line(*b, 0), "[1] 11");
  EXPECT_EQ(a->lines().size(), 1u);
  EXPECT_EQ(endpoint->counters().clients, 2u);
}

TEST_F(CommandEndpointTest, DisconnectCancelsPendingRequestsAndMonitor) {
  start(options());
  auto client = connect();
  client->send("[1] 5 r 0x1000 0\n[2] 6 r 0x1000 0\nmonitor\n");
  ASSERT_EQ(calls_soon(2), 2u);
  ASSERT_TRUE(until([&] { return remote.observers.size() == 1; }));
  remote.complete_ok(0, {1});
  EXPECT_EQ(line(*client, 0), "[1] 01");
  client->close();
  ASSERT_TRUE(until([&] { return !remote.cancelled.empty() && remote.observers.empty(); }));
  EXPECT_EQ(remote.cancelled, std::vector<RemoteAccess::RequestId>{remote.calls[1].id});
  EXPECT_TRUE(until([&] { return endpoint->counters().sessions == 0; }));
  remote.complete(1, RemoteOutcome{std::make_error_code(std::errc::operation_canceled), {}, {}});
}

// `printf '[1] 10 read 0x1008 0 vs\n' | socat -t 3 - UNIX-CONNECT:...`: the client's end of file
// comes before the answers, which it still reads. Every request already sent is answered, in
// order, nothing is cancelled, and then the endpoint closes.
TEST_F(CommandEndpointTest, HalfCloseStillGetsEveryAnswer) {
  start(options());
  auto client = connect();
  client->send("[1] 10 read 0x1008 0 vs\n[2] 5 r 0x1000 0 u8\n");
  client->shutdown_send();
  ASSERT_EQ(calls_soon(2), 2u);
  for (int i = 0; i < 20; ++i) {  // the end of file is read; nothing may be cancelled
    io.restart();
    io.poll();
  }
  EXPECT_TRUE(remote.cancelled.empty());
  remote.complete_ok(1, {7});
  remote.complete_ok(0, {'a', 'b'});
  EXPECT_TRUE(closed_by_endpoint(*client));
  EXPECT_EQ(client->received(), "[1] \"ab\"\r\n[2] 7\r\n");
  EXPECT_TRUE(remote.cancelled.empty());
  EXPECT_TRUE(until([&] { return endpoint->counters().sessions == 0; }));
}

// A last line without its LF before the end of file is a request too; a monitor feed ends at the
// end of file (it has no last answer), and a client with nothing pending is closed at once.
TEST_F(CommandEndpointTest, HalfCloseAnswersAnUnterminatedLineAndEndsTheMonitor) {
  start(options());
  auto client = connect();
  client->send("[1] monitor\n[2] 5 r 0x1000 0 u8");
  ASSERT_TRUE(until([&] { return remote.observers.size() == 1; }));
  EXPECT_TRUE(remote.calls.empty()) << "a line without its LF, before the end of file";
  client->shutdown_send();
  ASSERT_EQ(calls_soon(1), 1u);
  ASSERT_TRUE(until([&] { return remote.observers.empty(); }));
  remote.complete_ok(0, {9});
  EXPECT_TRUE(closed_by_endpoint(*client));
  EXPECT_EQ(client->received(), "[1] OK\r\n[2] 9\r\n");

  auto idle = connect();
  idle->shutdown_send();
  EXPECT_TRUE(closed_by_endpoint(*idle));
  EXPECT_EQ(idle->received(), "");
}

MonitorFrame frame(std::uint32_t module, std::uint32_t id, std::uint8_t byte) {
  MonitorFrame f;
  f.time_us = 1700000000000000 + byte;
  f.module_id = module;
  f.to_surface_bus = module != 0;
  f.frame = can::Frame::standard(id, {byte});
  return f;
}

TEST_F(CommandEndpointTest, MonitorSlowReaderGetsDropped) {
  auto o = options();
  o.monitor_queue_frames = 5;
  start(o);
  auto client = connect();
  client->send("[1] monitor\n");
  EXPECT_EQ(line(*client, 0), "[1] OK");
  // Twenty frames at once, faster than anything can be written: five queued, fifteen dropped.
  for (std::uint8_t i = 0; i < 20; ++i) remote.emit(frame(1, 0x185, i));
  const auto got = lines(*client, 7);
  EXPECT_EQ(got[1], "FRAME 1700000000000000 1 > 185#00");
  EXPECT_EQ(got[5], "FRAME 1700000000000004 1 > 185#04");
  EXPECT_EQ(got[6], "DROPPED 15");
  EXPECT_EQ(endpoint->counters().monitor_dropped, 15u);
  remote.emit(frame(0, 0x605, 0xAA));
  EXPECT_EQ(line(*client, 7), "FRAME 1700000000000170 0 < 605#AA");

  client->send("monitor module=2\n");
  EXPECT_EQ(line(*client, 8), "OK");
  remote.emit(frame(1, 0x185, 1));
  remote.emit(frame(2, 0x186, 2));
  EXPECT_EQ(line(*client, 9), "FRAME 1700000000000002 2 > 186#02");
  EXPECT_EQ(remote.observers.size(), 1u);  // one subscription per client
}

TEST_F(CommandEndpointTest, TcpAuthGoodBadMissingAndRoles) {
  auto o = options();
  o.tcp_port = free_tcp_port();
  o.clients = {{"bench", "c0ntr0l-token", EndpointRole::control},
               {"viewer", "m0n1t0r-token", EndpointRole::monitor}};
  start(o);
  EXPECT_EQ(endpoint->tcp_port(), o.tcp_port);

  auto missing = RawClient::tcp(o.tcp_port);
  missing->send("[1] 5 r 0x1000 0\n");
  EXPECT_EQ(line(*missing, 0), "[1] ERROR:401 #Authentication required.");
  EXPECT_TRUE(closed_by_endpoint(*missing));

  auto wrong = RawClient::tcp(o.tcp_port);
  wrong->send("auth c0ntr0l-tokeN\n");
  EXPECT_EQ(line(*wrong, 0), "ERROR:401 #Authentication required. wrong token");
  EXPECT_TRUE(closed_by_endpoint(*wrong));
  EXPECT_TRUE(remote.calls.empty());

  auto control = RawClient::tcp(o.tcp_port);
  send_bytewise(*control, "[1] auth c0ntr0l-token\n[2] 5 w 0x2000 0 u8 1\n");
  EXPECT_EQ(line(*control, 0), "[1] OK");
  ASSERT_EQ(calls_soon(1), 1u);
  remote.complete_ok(0);
  EXPECT_EQ(line(*control, 1), "[2] OK");

  auto viewer = RawClient::tcp(o.tcp_port);
  viewer->send(
      "[1] auth m0n1t0r-token\n[2] 5 r 0x1000 0 u8\n[3] 5 w 0x2000 0 u8 1\n[4] 5 start\n"
      "[5] 5 flash /etc/hostname\n[6] lss_store\n[7] 5 set node_id 6\n");
  EXPECT_EQ(line(*viewer, 0), "[1] OK");
  ASSERT_EQ(calls_soon(2), 2u);
  remote.complete_ok(1, {7});
  const auto got = lines(*viewer, 7);
  EXPECT_EQ(got[1], "[2] 7");
  for (std::size_t i = 2; i < 7; ++i) {
    EXPECT_EQ(got[i], "[" + std::to_string(i + 1) + "] ERROR:403 #Not permitted for role monitor.");
  }
  EXPECT_EQ(remote.calls.size(), 2u);
  const auto counters = endpoint->counters();
  EXPECT_EQ(counters.refused, 5u);
  EXPECT_EQ(counters.auth_failures, 2u);
  EXPECT_EQ(counters.errors, 7u);  // two 401, five 403
}

TEST_F(CommandEndpointTest, TcpOnlyOnLoopback) {
  auto o = options();
  o.tcp_port = free_tcp_port();
  o.tcp_address = "0.0.0.0";
  endpoint = std::make_unique<CommandEndpoint>(io.get_executor(), o, remote);
  try {
    endpoint->start();
    FAIL() << "started on 0.0.0.0";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("not a loopback address"), std::string::npos) << e.what();
  }
  // Nothing is left listening: the Unix socket it made is gone again.
  struct stat st {};
  EXPECT_NE(::lstat(o.unix_socket.c_str(), &st), 0);
}

TEST_F(CommandEndpointTest, SocketFileModeStaleReplacedOtherFilesRefused) {
  auto o = options();
  // A stale socket: bound by a process that is gone.
  {
    const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, o.unix_socket.c_str(), sizeof address.sun_path - 1);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
    ::close(fd);
  }
  start(o);
  struct stat st {};
  ASSERT_EQ(::lstat(o.unix_socket.c_str(), &st), 0);
  EXPECT_TRUE(S_ISSOCK(st.st_mode));
  EXPECT_EQ(st.st_mode & 0777, 0660u);
  auto client = connect();
  client->send("help lss\n");
  EXPECT_TRUE(lines(*client, 1).back().ends_with("\nOK"));

  // A second endpoint on the same live socket is refused.
  CommandEndpoint second(io.get_executor(), o, remote);
  EXPECT_THROW(second.start(), std::runtime_error);
  client->send("help\n");  // the first still serves
  EXPECT_TRUE(lines(*client, 2).back().ends_with("\nOK"));

  // Not a socket: never replaced.
  auto other = o;
  other.unix_socket = dir.file("config.yaml", "keep me\n");
  CommandEndpoint third(io.get_executor(), other, remote);
  try {
    third.start();
    FAIL() << "replaced a regular file";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("is not a socket"), std::string::npos) << e.what();
  }
  std::ifstream kept(other.unix_socket);
  std::string text;
  std::getline(kept, text);
  EXPECT_EQ(text, "keep me");

  endpoint->stop();
  EXPECT_TRUE(closed_by_endpoint(*client));
  EXPECT_NE(::lstat(o.unix_socket.c_str(), &st), 0) << "socket file left behind";
}

TEST_F(CommandEndpointTest, OverlongLineIsRefusedAndClosed) {
  auto o = options();
  o.max_line_bytes = 64;
  start(o);
  auto client = connect();
  client->send("[1] 5 w 0x2000 0 vs " + std::string(40, 'a') + "\n");  // 64 bytes: fits
  ASSERT_EQ(calls_soon(1), 1u);
  remote.complete_ok(0);
  EXPECT_EQ(line(*client, 0), "[1] OK");
  client->send(std::string(200, 'x'));
  EXPECT_EQ(line(*client, 1),
            "ERROR:101 #Syntax error. line longer than 64 bytes; connection closed");
  EXPECT_TRUE(closed_by_endpoint(*client));
}

TEST_F(CommandEndpointTest, BinaryGarbageIsAnsweredNotFatal) {
  start(options());
  auto client = connect();
  std::string garbage;
  for (int i = 0; i < 256; ++i) garbage += static_cast<char>(i);  // NUL, CR, LF and all others
  client->send(garbage);
  client->send("\n[9] 5 r 0x1000 0 u8\n");
  ASSERT_EQ(calls_soon(1), 1u);
  remote.complete_ok(0, {42});
  const auto got = lines(*client, 3);
  EXPECT_EQ(got[0].rfind("ERROR:101 #Syntax error. control byte 0x00", 0), 0u) << got[0];
  EXPECT_EQ(got[1].rfind("ERROR:101 #Syntax error. control byte 0x0B", 0), 0u) << got[1];
  EXPECT_EQ(got[2], "[9] 42");
}

TEST_F(CommandEndpointTest, ClientsBeyondMaxAreTurnedAway) {
  auto o = options();
  o.max_clients = 1;
  start(o);
  auto first = connect();
  first->send("[1] help lss\n");
  lines(*first, 1);
  auto second = connect();
  EXPECT_EQ(line(*second, 0),
            "ERROR:102 #Request not processed due to internal state. too many "
            "clients (1)");
  EXPECT_TRUE(closed_by_endpoint(*second));
  EXPECT_EQ(endpoint->counters().clients_refused, 1u);
  first->close();
  ASSERT_TRUE(until([&] { return endpoint->counters().sessions == 0; }));
  auto third = connect();
  third->send("[2] help lss\n");
  EXPECT_TRUE(lines(*third, 1).back().ends_with("\n[2] OK"));
}

TEST_F(CommandEndpointTest, StopClosesClientsAndCancelsTheirRequests) {
  start(options());
  auto client = connect();
  client->send("[1] 5 r 0x1000 0\n");
  ASSERT_EQ(calls_soon(1), 1u);
  endpoint->stop();
  EXPECT_TRUE(closed_by_endpoint(*client));
  EXPECT_EQ(remote.cancelled, std::vector<RemoteAccess::RequestId>{remote.calls[0].id});
  EXPECT_TRUE(until([&] { return endpoint->counters().sessions == 0; }));
  remote.complete(0, RemoteOutcome{std::make_error_code(std::errc::operation_canceled), {}, {}});
  EXPECT_THROW(RawClient::unix_socket(dir.path() + "/surface.sock"), std::runtime_error);
}

}  // namespace
}  // namespace canbridge::bridge
