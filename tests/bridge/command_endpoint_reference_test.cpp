// CANopenNode's CiA 309-3 command-line syntax cases against the real command endpoint, byte for
// byte. The expected answers are written from the reference gateway's documented format, not
// from canbridge's output: CANopenNode's 309/CO_gateway_ascii.c answers `[%d] OK\r\n`, a value as
// `[%d] <value>\r\n` (u16 with "%u", x16 with "0x%04X", vs between double quotes, no datatype as
// space-separated hex bytes), errors as `[%d] ERROR:%d #<description>\r\n` and SDO aborts as
// `[%d] ERROR:0x%08X #<description>\r\n` (its descriptions are quoted in
// tests/canopen/ascii_reference_test.cpp), and a blank or comment-only line with `\r\n` alone.
// Its parser gives 100 to an unknown command or `set` word, 101 to every other malformed line and
// 107 to a node number above 127. Behind the endpoint, one answering node (4) on the default
// network stands where canopend would have its bus.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/post.hpp>
#include <cstring>
#include <filesystem>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "bridge/command_endpoint.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::bridge {
namespace {

namespace asio = boost::asio;

// Node 4 of net 0 with a few objects; every other node is silent, which a gateway reports as
// the SDO time-out abort, as canopend's SDO client does. Answers later than the call, on the
// endpoint's executor, as the surface does.
class ReferenceNode : public RemoteAccess {
 public:
  explicit ReferenceNode(asio::any_io_executor executor) : executor_(std::move(executor)) {}

  std::vector<NetworkInfo> networks() const override { return {{0, 0, "", false, true}}; }
  RequestId sdo(RemoteSdo request, Done done) override {
    if (request.target.node != kNode) return answer(std::move(done), abort(0x05040000));
    const auto it = objects_.find({request.index, request.sub});
    if (it == objects_.end()) return answer(std::move(done), abort(0x06020000));
    Object& object = it->second;
    if (request.upload) return answer(std::move(done), {{}, object.value, {}});
    if (!object.writable) return answer(std::move(done), abort(0x06010002));
    if (request.data.size() != object.value.size()) {
      return answer(std::move(done), abort(0x06070010));
    }
    object.value = request.data;
    return answer(std::move(done), {});
  }
  RequestId nmt(RemoteTarget, NmtCommand command, Done done) override {
    nmt_commands.push_back(command);
    return answer(std::move(done), {});
  }
  RequestId set_node_id(RemoteTarget, canopen::NodeId, Done done) override {
    return answer(std::move(done), {});
  }
  RequestId flash(RemoteTarget, std::vector<std::uint8_t>,
                  std::function<void(const FlashProgress&)>, Done done) override {
    return answer(std::move(done), {});
  }
  RequestId lss(NetworkNumber, std::string, std::vector<std::uint32_t>, Done done) override {
    return answer(std::move(done), {});
  }
  void cancel(RequestId) override {}
  void nodes(NetworkNumber,
             std::function<void(std::vector<NodeRow>, std::error_code)> done) override {
    asio::post(executor_, [done = std::move(done)] { done({}, {}); });
  }
  std::uint64_t subscribe(std::function<void(const MonitorFrame&)>) override { return 1; }
  void unsubscribe(std::uint64_t) override {}

  std::vector<NmtCommand> nmt_commands;  // on the executor's thread; read after the io stopped

 private:
  static constexpr canopen::NodeId kNode = 4;
  struct Object {
    std::vector<std::uint8_t> value;
    bool writable = true;
  };
  static RemoteOutcome abort(std::uint32_t code) { return {canopen::abort_error(code), {}, {}}; }
  RequestId answer(Done done, RemoteOutcome outcome) {
    asio::post(executor_,
               [done = std::move(done), outcome = std::move(outcome)] { done(outcome); });
    return ++next_;
  }

  asio::any_io_executor executor_;
  std::map<std::pair<std::uint16_t, std::uint8_t>, Object> objects_{
      {{0x1000, 0}, {{0x91, 0x01, 0x0F, 0x00}, false}},  // device type, read only
      {{0x1008, 0}, {{'C', 'A', 'N', 'o', 'p', 'e', 'n', ' ', '"', '4', '"'}, false}},
      {{0x1017, 0}, {{0x00, 0x00}, true}},  // producer heartbeat time, 0 ms
      {{0x1018, 1}, {{0xA2, 0x01, 0x00, 0x00}, false}},
  };
  RequestId next_ = 0;
};

// A plain Unix socket client with a receive deadline: one request line out, its answer in (the
// bytes up to and including the first CR LF, which ends a 309-3 answer).
class LineClient {
 public:
  explicit LineClient(const std::string& path) : fd_(::socket(AF_UNIX, SOCK_STREAM, 0)) {
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::strncpy(address.sun_path, path.c_str(), sizeof address.sun_path - 1);
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
      ::close(fd_);
      throw std::runtime_error("connect " + path + ": " + std::strerror(errno));
    }
    timeval deadline{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &deadline, sizeof deadline);
  }
  ~LineClient() { ::close(fd_); }
  LineClient(const LineClient&) = delete;
  LineClient& operator=(const LineClient&) = delete;

  // Sends `request` and an LF; returns its answer with its CR LF ("" when none came in time).
  std::string ask(const std::string& request) {
    const std::string line = request + "\n";
    if (::send(fd_, line.data(), line.size(), MSG_NOSIGNAL) != static_cast<ssize_t>(line.size())) {
      return {};
    }
    for (;;) {
      const auto end = pending_.find("\r\n");
      if (end != std::string::npos) {
        std::string answer = pending_.substr(0, end + 2);
        pending_.erase(0, end + 2);
        return answer;
      }
      char buf[4096];
      const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
      if (n <= 0) return {};
      pending_.append(buf, static_cast<std::size_t>(n));
    }
  }

 private:
  int fd_;
  std::string pending_;
};

struct SyntaxCase {
  const char* request;
  const char* reference_answer;
};

// Reference cases, each answered on its own. `set node 4` early on: the later lines without a node
// are addressed to it.
const SyntaxCase kReferenceCases[] = {
    // SDO upload and download, with and without the long command names.
    {"[1] 4 read 0x1017 0 u16", "[1] 0\r\n"},
    {"[2] 4 write 0x1017 0 u16 1000", "[2] OK\r\n"},
    {"[3] 4 r 0x1017 0 u16", "[3] 1000\r\n"},
    {"[4] 4 r 0x1017 0 x16", "[4] 0x03E8\r\n"},
    {"[5] 4 r 0x1017 0", "[5] E8 03\r\n"},  // no datatype: hex bytes
    {"[6] 4 w 0x1017 0 u16 0x01F4", "[6] OK\r\n"},
    {"[7] 4 read 0x1018 1 u32", "[7] 418\r\n"},
    {"[8] 4 read 0x1008 0 vs", "[8] \"CANopen \"\"4\"\"\"\r\n"},
    {"[9] 0 4 read 0x1017 0 u16", "[9] 500\r\n"},  // net 0 written out
    // NMT.
    {"[10] 4 start", "[10] OK\r\n"},
    {"[11] 4 stop", "[11] OK\r\n"},
    {"[12] 4 preop", "[12] OK\r\n"},
    {"[13] 4 preoperational", "[13] OK\r\n"},
    {"[14] 4 reset node", "[14] OK\r\n"},
    {"[15] 4 reset comm", "[15] OK\r\n"},
    {"[16] 4 reset communication", "[16] OK\r\n"},
    {"[17] 0 start", "[17] OK\r\n"},  // every node
    // Session settings and the default node.
    {"[18] read 0x1017 0 u16", "[18] ERROR:105 #No default node set.\r\n"},
    {"[19] set node 4", "[19] OK\r\n"},
    {"[20] read 0x1017 0 u16", "[20] 500\r\n"},
    {"[21] set sdo_timeout 500", "[21] OK\r\n"},
    {"[22] set sdo_block 0", "[22] OK\r\n"},
    {"[23] set network 0", "[23] OK\r\n"},
    {"[24] set frob 1", "[24] ERROR:100 #Request not supported.\r\n"},
    // Errors the parser finds.
    {"[25] 4 frob", "[25] ERROR:100 #Request not supported.\r\n"},
    {"[26] 4 read 0x1017", "[26] ERROR:101 #Syntax error.\r\n"},
    {"[27] 4 read 0x1017 0 u99", "[27] ERROR:101 #Syntax error.\r\n"},
    {"[28] 4 write 0x1017 0 u16", "[28] ERROR:101 #Syntax error.\r\n"},
    {"[29] 4 write 0x1017 0 u16 70000", "[29] ERROR:101 #Syntax error.\r\n"},
    {"[30] 4 reset frob", "[30] ERROR:101 #Syntax error.\r\n"},
    {"[31] 4 read 0x10000 0 u8", "[31] ERROR:101 #Syntax error.\r\n"},
    {"[32] 1 2 3 read 0x1017 0 u16", "[32] ERROR:101 #Syntax error.\r\n"},
    {"[33] 4 start now", "[33] ERROR:101 #Syntax error.\r\n"},
    {"[34] set node 128", "[34] ERROR:101 #Syntax error.\r\n"},
    {"[35] help frob", "[35] ERROR:101 #Syntax error.\r\n"},
    {"[36] 200 read 0x1017 0 u16", "[36] ERROR:107 #Unsupported node.\r\n"},
    {"[37] 0 200 start", "[37] ERROR:107 #Unsupported node.\r\n"},
    {"[38] 70000 4 read 0x1017 0 u16", "[38] ERROR:106 #Unsupported net.\r\n"},
    // SDO aborts, with the CiA 301 description the reference gives each code.
    {"[39] 4 read 0x6000 0 u8", "[39] ERROR:0x06020000 #Object does not exist.\r\n"},
    {"[40] 4 write 0x1000 0 u32 1",
     "[40] ERROR:0x06010002 #Attempt to write a read only object.\r\n"},
    {"[41] 4 write 0x1017 0 u32 1",
     "[41] ERROR:0x06070010 #Data type does not match, length of service parameter does not "
     "match.\r\n"},
    {"[42] 9 read 0x1017 0 u16", "[42] ERROR:0x05040000 #SDO protocol timed out.\r\n"},
    // Case, comments and blank lines.
    {"[43] 4 READ 0x1017 0 U16", "[43] 500\r\n"},
    {"[44] 4 read 0x1017 0 u16 # the heartbeat", "[44] 500\r\n"},
    {"# a comment line", "\r\n"},
    {"", "\r\n"},
};

class CommandEndpointReference : public ::testing::Test {
 protected:
  void start(CommandEndpointOptions options) {
    options.unix_socket = path_;
    endpoint_ = std::make_unique<CommandEndpoint>(io_.get_executor(), options, node_);
    endpoint_->start();
    thread_ = std::thread([this] { io_.run(); });
  }
  void TearDown() override {
    asio::post(io_, [this] { endpoint_->stop(); });
    work_.reset();
    if (thread_.joinable()) thread_.join();
    endpoint_.reset();
    std::filesystem::remove(path_);
  }

  asio::io_context io_;
  asio::executor_work_guard<asio::io_context::executor_type> work_{io_.get_executor()};
  ReferenceNode node_{io_.get_executor()};
  std::string path_ = (std::filesystem::temp_directory_path() /
                       ("canbridge-reference-" + std::to_string(::getpid()) + ".sock"))
                          .string();
  std::unique_ptr<CommandEndpoint> endpoint_;
  std::thread thread_;
};

// With error_detail off, every answer is the reference gateway's, byte for byte.
TEST_F(CommandEndpointReference, SyntaxCasesAreAnsweredAsTheReferenceGatewayByteForByte) {
  CommandEndpointOptions options;
  options.error_detail = false;
  start(options);
  LineClient client(path_);
  for (const SyntaxCase& c : kReferenceCases) {
    EXPECT_EQ(client.ask(c.request), c.reference_answer) << c.request;
  }
}

// With canbridge's reasons on (the default), an error line still starts with the reference's
// bytes, the reason after its description; `set error_detail 0` gives the reference's line.
TEST_F(CommandEndpointReference, ReasonsFollowTheReferenceTextAndCanBeTurnedOff) {
  start(CommandEndpointOptions{});
  LineClient client(path_);
  const std::string with_reason = client.ask("[1] 200 read 0x1017 0 u16");
  EXPECT_EQ(with_reason.rfind("[1] ERROR:107 #Unsupported node. ", 0), 0u) << with_reason;
  EXPECT_TRUE(with_reason.ends_with("\r\n"));
  EXPECT_GT(with_reason.size(), std::string("[1] ERROR:107 #Unsupported node.\r\n").size());
  EXPECT_EQ(client.ask("[2] set error_detail 0"), "[2] OK\r\n");
  EXPECT_EQ(client.ask("[3] 200 read 0x1017 0 u16"), "[3] ERROR:107 #Unsupported node.\r\n");
  EXPECT_EQ(client.ask("[4] 4 frob"), "[4] ERROR:100 #Request not supported.\r\n");
  EXPECT_EQ(client.ask("[5] set error_detail 1"), "[5] OK\r\n");
  EXPECT_NE(client.ask("[6] 4 frob"), "[6] ERROR:100 #Request not supported.\r\n");
}

// `help`: the reference's help is one answer, its lines separated by LF and only its end a
// CR LF, so that cocomm prints all of it. canbridge's text is its own (its extensions, and a
// closing `[<seq>] OK`); the datatypes it lists are the reference's.
TEST_F(CommandEndpointReference, HelpIsOneAnswerWithTheReferencesDatatypes) {
  CommandEndpointOptions options;
  options.error_detail = false;
  start(options);
  LineClient client(path_);
  for (const std::string topic : {"", " datatype", " lss"}) {
    const std::string help = client.ask("[7] help" + topic);
    ASSERT_TRUE(help.ends_with("\n[7] OK\r\n")) << help;
    EXPECT_EQ(help.find("\r\n"), help.size() - 2) << "a CR LF inside the answer: " << help;
  }
  const std::string datatypes = client.ask("[8] help datatype");
  for (const char* type :
       {"\nb ", "\ni8, i16, i32, i64 ", "\nu8, u16, u32, u64 ", "\nx8, x16, x32, x64 ",
        "\nr32, r64 ", "\nvs ", "\nos, us ", "\nd ", "\nhex "}) {
    EXPECT_NE(datatypes.find(type), std::string::npos) << type << " missing in: " << datatypes;
  }
  // After help, the next answer is the next request's.
  EXPECT_EQ(client.ask("[9] 4 r 0x1017 0 u16"), "[9] 0\r\n");
}

}  // namespace
}  // namespace canbridge::bridge
