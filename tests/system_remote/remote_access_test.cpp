// Remote access end to end (issue 16) in the vcan rig: a real canbridge surface (bus vcan0, its
// CiA 309-3 command endpoint on a Unix socket in a temp dir), a real gateway (module 1 = vcan1,
// cia301, net 2; module 2 = vcan2, qd, net 3) on a psk backbone with keys made at run time, and
// canbridge-sim with rig.yaml. The endpoint is driven by EndpointClient (raw protocol bytes,
// nothing of canbridge's client code); the `canbridge` subcommands run as child processes. What
// a command does on a module bus is checked there: candump (can-utils) shows the NMT and LSS
// frames, a raw-socket BusLog the nodes' heartbeat states and the SDO protocol used. A capture is
// read back by tshark. Everything awaited is a line or a frame with a deadline; nothing sleeps.
//
// Ids (gateway config below): module 1 local 10, 11 -> surface 42, 43; module 2 qd local 1, 2 ->
// surface 5, 6, fpga local 3 -> surface 7 (local 4 -> 8 is free for set-node-id).
#include <gtest/gtest.h>
#include <signal.h>

#include <array>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/bus_log.hpp"
#include "tests/support/process.hpp"
#include "tests/support/rig_processes.hpp"
#include "tests/support/temp_key_dir.hpp"
#include "tests/system_remote/endpoint_client.hpp"
#include "tests/system_remote/remote_rig_configs.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using test::BusLog;
using test::ChildProcess;
using test::EndpointClient;
using test::RigProcesses;

// Upper bound of one awaited event in the (slow) UML guest; the events come much sooner.
constexpr auto kEvent = 10s;
// A 256 KiB flash through the gateway: block download on the module bus plus two boot-ups.
constexpr auto kFlash = 120s;
const std::string kSourceDir = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/system_remote/";

// CRC-32 (IEEE 802.3, reflected 0xEDB88320), the checksum the qd loader publishes in 1F56h:01;
// written out here so the test does not trust the sim's own code for the expected value.
std::uint32_t crc32(const std::vector<std::uint8_t>& data) {
  std::uint32_t crc = 0xFFFFFFFFu;
  for (const std::uint8_t byte : data) {
    crc ^= byte;
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

std::vector<std::uint8_t> pseudo_random(std::size_t size, std::uint32_t seed) {
  std::mt19937 gen(seed);
  std::vector<std::uint8_t> v(size);
  for (auto& b : v) b = static_cast<std::uint8_t>(gen());
  return v;
}

// Image for the simulated loader: the application, then its CRC-32 little-endian.
std::vector<std::uint8_t> firmware_image(const std::vector<std::uint8_t>& application) {
  std::vector<std::uint8_t> image = application;
  const std::uint32_t crc = crc32(application);
  for (int i = 0; i < 4; ++i) image.push_back(static_cast<std::uint8_t>(crc >> (8 * i)));
  return image;
}

std::string base64(const std::vector<std::uint8_t>& data) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  std::size_t i = 0;
  for (; i + 2 < data.size(); i += 3) {
    const std::uint32_t v = (data[i] << 16) | (data[i + 1] << 8) | data[i + 2];
    for (int s = 18; s >= 0; s -= 6) out += kAlphabet[(v >> s) & 0x3F];
  }
  if (i + 1 == data.size()) {
    const std::uint32_t v = data[i] << 16;
    out += kAlphabet[(v >> 18) & 0x3F];
    out += kAlphabet[(v >> 12) & 0x3F];
    out += "==";
  } else if (i + 2 == data.size()) {
    const std::uint32_t v = (data[i] << 16) | (data[i + 1] << 8);
    out += kAlphabet[(v >> 18) & 0x3F];
    out += kAlphabet[(v >> 12) & 0x3F];
    out += kAlphabet[(v >> 6) & 0x3F];
    out += '=';
  }
  return out;
}

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string write_file(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  return path;
}

std::string joined(const std::vector<std::string>& lines) {
  std::string all;
  for (const auto& l : lines) all += l + "\n";
  return all;
}

bool is_heartbeat(const Frame& f, std::uint32_t local, std::uint8_t state) {
  return f.id == 0x700u + local && f.len == 1 && f.data[0] == state && !f.is_remote();
}

bool any_failure() {
  return ::testing::UnitTest::GetInstance()->failed_test_count() > 0;
}

class RemoteAccess : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    keys_ = std::make_unique<test::TempKeyDir>();
    const std::string dir = keys_->path() + "/";
    socket_path_ = dir + "surface.sock";
    const std::string key = keys_->key("remote-gateway.key");
    test::write_remote_rig_configs(*keys_, key, socket_path_, 1000);
    std::filesystem::copy_file(kSourceDir + "rig.yaml", dir + "rig.yaml");

    vcan1_ = std::make_unique<BusLog>("vcan1");
    vcan2_ = std::make_unique<BusLog>("vcan2");
    // can-utils' view of the NMT and LSS frames the gateway writes on the module buses (and a
    // marker id, 7FFh, that shows when candump listens: cansend until it shows the marker).
    candump_ = std::make_unique<ChildProcess>(std::vector<std::string>{
        "candump", "-L", "vcan1,000:7FF,7E5:7FF,7FF:7FF", "vcan2,000:7FF,7FF:7FF"});
    for (const std::string bus : {"vcan1", "vcan2"}) {
      bool listening = false;
      for (int i = 0; i < 50 && !listening; ++i) {
        ASSERT_EQ(test::run({"cansend", bus, "7FF#A5"}).status, 0);
        listening = candump_->wait_for_line(bus + " 7FF#A5", 100ms);
      }
      ASSERT_TRUE(listening) << candump_->output();
    }

    processes_ =
        std::make_unique<RigProcesses>(test::RigOptions{.canbridge = CANBRIDGE_BIN,
                                                        .sim = CANBRIDGE_SIM_BIN,
                                                        .link_emulator = {},
                                                        .link_emulator_args = {},
                                                        .config_dir = dir,
                                                        .port_placeholder = "${LINK_PORT}",
                                                        .surface_name = "remote-surface",
                                                        .gateway_name = "remote-gateway",
                                                        .sim_ready = "ready 6 nodes on 2 buses",
                                                        .event_timeout = kEvent});
    processes_->start();
    if (::testing::Test::HasFatalFailure()) return;
    ASSERT_TRUE(std::filesystem::exists(socket_path_)) << processes_->surface->output();
    // Every node has booted and beats (qd nodes: after their loader's boot-up).
    // A pair, not a structured binding: clang 14 (Debian 12) cannot capture one in a lambda.
    for (const auto& node : {std::pair{vcan1_.get(), 10u},
                             {vcan1_.get(), 11u},
                             {vcan2_.get(), 1u},
                             {vcan2_.get(), 2u},
                             {vcan2_.get(), 3u}}) {
      const unsigned local = node.second;
      ASSERT_TRUE(node.first->wait_for(
          0, [local](const Frame& f) { return is_heartbeat(f, local, 0x7F); }, kEvent))
          << "node " << local << " does not beat";
    }
    ready_ = true;
    ready_at_ = std::chrono::steady_clock::now();
  }

  static void TearDownTestSuite() {
    if (processes_) {
      processes_->stop();
      processes_->print_logs(any_failure());
    }
    processes_.reset();
    if (any_failure() && candump_) std::cout << "--- candump\n" << candump_->output();
    candump_.reset();
    vcan1_.reset();
    vcan2_.reset();
    keys_.reset();
    ready_ = false;
  }

  void SetUp() override {
    ASSERT_TRUE(ready_) << "the rig did not start";
    ASSERT_NO_FATAL_FAILURE(processes_->expect_running());
    client_ = std::make_unique<EndpointClient>(socket_path_);
  }
  void TearDown() override {
    if (client_) {
      EXPECT_EQ(client_->bare_lf(), 0) << "response lines must end with CR LF";
    }
  }

  // "[seq] <request>" and the response without its "[seq] ", failing when the echo is missing.
  std::string ask(const std::string& request, std::chrono::milliseconds timeout = kEvent) {
    const std::string seq = "[" + std::to_string(++seq_) + "] ";
    const std::string response = client_->ask(seq + request, timeout);
    EXPECT_TRUE(response.starts_with(seq)) << request << " -> '" << response << "'";
    return response.starts_with(seq) ? response.substr(seq.size()) : response;
  }

  // Runs `canbridge <args> --endpoint <socket>`; returns its exit status and output.
  static test::RunResult cli(std::vector<std::string> args,
                             std::chrono::milliseconds timeout = kEvent) {
    std::vector<std::string> argv{CANBRIDGE_BIN};
    argv.insert(argv.end(), args.begin(), args.end());
    argv.insert(argv.end(), {"--endpoint", socket_path_});
    return test::run(argv, timeout);
  }

  // The next frame on `log` at or after `from` that matches.
  static std::optional<BusLog::Found> await(BusLog& log, std::size_t from,
                                            const std::function<bool(const Frame&)>& match) {
    return log.wait_for(from, match, kEvent);
  }

  static inline std::unique_ptr<test::TempKeyDir> keys_;
  static inline std::string socket_path_;
  static inline std::unique_ptr<BusLog> vcan1_, vcan2_;
  static inline std::unique_ptr<ChildProcess> candump_;
  static inline std::unique_ptr<RigProcesses> processes_;
  static inline bool ready_ = false;
  // Every node had booted by then (the quiet one too: it boots with the others).
  static inline std::chrono::steady_clock::time_point ready_at_{};
  std::unique_ptr<EndpointClient> client_;
  int seq_ = 0;
};

// The request arrives one byte per write(2) and the response is still one line, CR LF ended.
TEST_F(RemoteAccess, RequestSentByteByByteIsAnswered) {
  client_->send_byte_by_byte("[7] 2 10 read 0x2010 0 u32 # a comment\r\n");
  EXPECT_EQ(client_->line(kEvent).value_or("<none>"), "[7] 305419896");
  // Without a sequence number the response has none; `r` is `read`; net 0 = surface ids.
  client_->send_byte_by_byte("42 r 0x2010 0 u32\n");
  EXPECT_EQ(client_->line(kEvent).value_or("<none>"), "305419896");
  // A comment-only line is answered with an empty line, as CANopenNode's gateway does; the
  // next answer is the next request's.
  client_->send("# nothing\n[8] 0 43 r 0x1018 2 u32\n");
  EXPECT_EQ(client_->line(kEvent).value_or("<none>"), "");
  EXPECT_EQ(client_->line(kEvent).value_or("<none>"), "[8] 258");
}

// Every 309-3 datatype class written and read back on the cia301 node (net 2, local 10).
TEST_F(RemoteAccess, EveryDatatypeWritesAndReadsBack) {
  struct Case {
    const char* type;
    const char* index;
    std::string value;     // as written
    std::string expected;  // as read back with the same type
  };
  const std::string domain = base64(pseudo_random(1000, 16));
  const std::vector<Case> cases = {
      {"b", "0x2000", "1", "1"},
      {"u8", "0x2001", "200", "200"},
      {"u16", "0x2002", "65535", "65535"},
      {"u32", "0x2003", "4000000000", "4000000000"},
      {"u64", "0x2004", "18446744073709551615", "18446744073709551615"},
      {"i8", "0x2005", "-128", "-128"},
      {"i16", "0x2006", "-1234", "-1234"},
      {"i32", "0x2007", "-2000000000", "-2000000000"},
      {"i64", "0x2008", "-9000000000000000000", "-9000000000000000000"},
      {"r32", "0x2009", "1.5", "1.5"},
      {"r64", "0x200A", "-2.25e+100", "-2.25e+100"},
      {"vs", "0x200B", "\"said \"\"hi\"\" twice\"", "\"said \"\"hi\"\" twice\""},
      {"os", "0x200C", "AAEC/w==", "AAEC/w=="},
      {"us", "0x2101", "aABpAA==", "aABpAA=="},
      {"d", "0x2100", domain, domain},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(std::string(c.type) + " " + c.index);
    EXPECT_EQ(ask(std::string("2 10 w ") + c.index + " 0 " + c.type + " " + c.value), "OK");
    EXPECT_EQ(ask(std::string("2 10 r ") + c.index + " 0 " + c.type), c.expected);
  }
  // x types print hex (CANopenNode: 0x and upper-case digits) and parse it.
  EXPECT_EQ(lower(ask("2 10 r 0x2010 0 x32")), "0x12345678");
  EXPECT_EQ(lower(ask("2 10 r 0x2001 0 x8")), "0xc8");
  EXPECT_EQ(ask("2 10 w 0x2002 0 x16 0x1A2B"), "OK");
  EXPECT_EQ(ask("2 10 r 0x2002 0 u16"), "6699");
  // hex, and no datatype at all: the bytes as two-digit hex separated by spaces.
  EXPECT_EQ(lower(ask("2 10 r 0x2010 0 hex")), "78 56 34 12");
  EXPECT_EQ(lower(ask("2 10 r 0x2010 0")), "78 56 34 12");
  // The same node by its surface id on net 0: the value written above through net 2.
  EXPECT_EQ(ask("0 42 r 0x2003 0 u32"), "4000000000");
}

// Errors: unknown net and node, an SDO abort with its text, no default node, a bad command.
TEST_F(RemoteAccess, ErrorsNameTheProblem) {
  EXPECT_TRUE(ask("9 1 r 0x1000 0 u32").starts_with("ERROR:106")) << "unknown net";
  // A module's net reaches local ids the surface does not map: nobody answers there.
  EXPECT_EQ(ask("set sdo_timeout 300"), "OK");
  EXPECT_TRUE(
      std::regex_match(ask("2 99 r 0x1000 0 u32"), std::regex("ERROR:(0x05040000|107) #.*")));
  EXPECT_EQ(ask("set sdo_timeout 1000"), "OK");
  EXPECT_TRUE(ask("0 99 r 0x1000 0 u32").starts_with("ERROR:107")) << "unknown surface node";
  const std::string abort = ask("2 10 r 0x6666 0 u32");
  EXPECT_TRUE(abort.starts_with("ERROR:0x06020000 #")) << abort;
  EXPECT_TRUE(ask("r 0x1000 0 u32").starts_with("ERROR:105")) << "no default node";
  EXPECT_TRUE(std::regex_match(ask("2 10 frobnicate 1 2"), std::regex("ERROR:10[01] #.*")));
  EXPECT_TRUE(std::regex_match(ask("2 10 r 0x2003 0 nosuchtype"), std::regex("ERROR:10[01] #.*")));
  // The connection survives every error.
  EXPECT_EQ(ask("2 10 r 0x2010 0 u32"), "305419896");
}

// set network / set node make the address optional; set sdo_block switches the protocol seen on
// the module bus; set sdo_timeout bounds a request to a node that does not answer.
TEST_F(RemoteAccess, SetCommandsChangeTheSession) {
  EXPECT_EQ(ask("set network 2"), "OK");
  EXPECT_EQ(ask("set node 10"), "OK");
  EXPECT_EQ(ask("r 0x2010 0 u32"), "305419896");
  EXPECT_EQ(ask("set network 3"), "OK");
  EXPECT_EQ(ask("set node 1"), "OK");  // the qd node
  EXPECT_EQ(ask("r 0x1008 0 vs"), "\"canbridge remote qd module\"");

  const std::string data = base64(pseudo_random(2048, 99));
  EXPECT_EQ(ask("set sdo_block 0"), "OK");
  std::size_t mark = vcan1_->mark();
  EXPECT_EQ(ask("2 11 w 0x2100 0 d " + data), "OK");
  // Segmented: initiate download with size indicated (0x21) from the gateway as 0x60B.
  EXPECT_TRUE(await(*vcan1_, mark, [](const Frame& f) {
    return f.id == 0x60B && f.data[0] == 0x21;
  })) << "no segmented initiate on vcan1";
  EXPECT_EQ(ask("set sdo_block 1"), "OK");
  mark = vcan1_->mark();
  EXPECT_EQ(ask("2 11 r 0x2100 0 d"), data);
  // Block upload initiate: ccs 5 (0xA0..), subcommand 0 (initiate).
  EXPECT_TRUE(await(*vcan1_, mark, [](const Frame& f) {
    return f.id == 0x60B && (f.data[0] & 0xE3) == 0xA0;
  })) << "no block upload initiate on vcan1";
  EXPECT_EQ(ask("set sdo_block 0"), "OK");

  // A stopped node does not serve SDO: the request times out after the session's timeout.
  EXPECT_EQ(ask("2 11 stop"), "OK");
  EXPECT_EQ(ask("set sdo_timeout 300"), "OK");
  auto t0 = std::chrono::steady_clock::now();
  EXPECT_TRUE(ask("2 11 r 0x1000 0 u32").starts_with("ERROR:0x05040000"));
  const auto short_wait = std::chrono::steady_clock::now() - t0;
  EXPECT_EQ(ask("set sdo_timeout 2500"), "OK");
  t0 = std::chrono::steady_clock::now();
  EXPECT_TRUE(ask("2 11 r 0x1000 0 u32").starts_with("ERROR:0x05040000"));
  const auto long_wait = std::chrono::steady_clock::now() - t0;
  EXPECT_GE(long_wait, 2400ms);  // never early
  EXPECT_LT(short_wait, 2400ms) << "set sdo_timeout 300 was not applied";
  EXPECT_EQ(ask("2 11 preop"), "OK");
}

// NMT through the endpoint: each command's frame on the module bus (candump) with the local id,
// and the node's next heartbeat in the commanded state. net 0 addresses by surface id.
TEST_F(RemoteAccess, NmtCommandsReachTheModuleBus) {
  struct Case {
    std::string request;
    std::string frame;  // candump -L: "vcan2 000#0201"
    BusLog* bus;
    std::uint32_t local;
    std::uint8_t state;  // heartbeat state after it
  };
  const std::vector<Case> cases = {
      {"3 1 stop", "vcan2 000#0201", vcan2_.get(), 1, 0x04},
      {"3 1 start", "vcan2 000#0101", vcan2_.get(), 1, 0x05},
      {"0 5 preop", "vcan2 000#8001", vcan2_.get(), 1, 0x7F},  // surface 5 = module 2 local 1
      {"3 1 preoperational", "vcan2 000#8001", vcan2_.get(), 1, 0x7F},
      {"3 2 reset comm", "vcan2 000#8202", vcan2_.get(), 2, 0x00},
      {"2 10 reset communication", "vcan1 000#820A", vcan1_.get(), 10, 0x00},
      {"0 43 reset node", "vcan1 000#810B", vcan1_.get(), 11, 0x00},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.request);
    const std::size_t mark = c.bus->mark();
    EXPECT_EQ(ask(c.request), "OK");
    EXPECT_TRUE(candump_->wait_for_line(c.frame, kEvent)) << candump_->output();
    EXPECT_TRUE(
        await(*c.bus, mark, [&](const Frame& f) { return is_heartbeat(f, c.local, c.state); }))
        << "no heartbeat state " << int(c.state);
  }
  // Node 0: every node of the module.
  const std::size_t mark = vcan2_->mark();
  EXPECT_EQ(ask("3 0 start"), "OK");
  EXPECT_TRUE(candump_->wait_for_line("vcan2 000#0100", kEvent)) << candump_->output();
  for (std::uint32_t local : {1u, 2u, 3u}) {
    EXPECT_TRUE(await(*vcan2_, mark, [&](const Frame& f) { return is_heartbeat(f, local, 5); }))
        << "local " << local << " not operational";
  }
  EXPECT_EQ(ask("3 0 preop"), "OK");
  EXPECT_TRUE(candump_->wait_for_line("vcan2 000#8000", kEvent)) << candump_->output();
}

// `nodes`: one line per node of the two modules, fields in the documented order, then OK.
TEST_F(RemoteAccess, NodesListsEveryNode) {
  // The gateway learns a node's kind from an answer with its device type (1000h:00), never by
  // asking itself: read it once, as a master would at boot.
  const std::string device_type = ask("2 10 read 0x1000 0 u32");
  // A node reset by an earlier test has booted again and is watched from its next heartbeat
  // (100 ms later): list until every beating node shows one, within kEvent.
  std::vector<std::string> lines;
  std::string seq;  // the answer the rows are checked in
  int bare_lf = 0;  // of that answer
  const auto until = std::chrono::steady_clock::now() + kEvent;
  for (int n = 50;; ++n) {
    seq = "[" + std::to_string(n) + "]";
    client_->send(seq + " nodes\n");
    lines = client_->lines_until(seq + " OK", kEvent);
    bare_lf = client_->take_bare_lf();
    const auto without_age = std::count_if(lines.begin(), lines.end(), [](const std::string& l) {
      return l.find(" hb_age_ms=-") != std::string::npos;
    });
    if (without_age <= 1 || std::chrono::steady_clock::now() > until) break;  // 1: the quiet node
  }
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines.back(), seq + " OK") << joined(lines);
  // One answer, one CR LF, as help: every row ends in LF alone, so that cocomm prints them all.
  EXPECT_EQ(static_cast<std::size_t>(bare_lf), lines.size() - 1) << joined(lines);
  const std::regex row(
      "\\" + seq.substr(0, seq.size() - 1) +
      "\\] node net=([0-9]+) module=([0-9]+) gateway=remote-gateway local=([0-9]+) "
      "surface=([0-9]+|-) profile=([a-z0-9]+) kind=(\\S+) "
      "state=(boot-up|stopped|operational|pre-operational|loader|lost) hb_age_ms=([0-9]+|-) "
      "boot_count=([0-9]+) emcy=(\\S+)");
  std::map<std::string, std::string> seen;  // "net/local" -> surface
  for (const auto& l : lines) {
    std::smatch m;
    if (!std::regex_match(l, m, row)) continue;
    seen[m[1].str() + "/" + m[3].str()] = m[4].str();
    const bool quiet = m[1].str() == "2" && m[3].str() == "12";  // no heartbeat (1017h = 0)
    EXPECT_EQ(m[8].str() == "-", quiet) << "a beating node has a heartbeat age: " << l;
    if (m[1].str() == "2" && m[3].str() == "10") {
      const auto type = std::stoul(device_type);
      EXPECT_EQ(m[6].str(), (type & 0xFFFFu) ? "CiA" + std::to_string(type & 0xFFFFu)
                                             : "mfr-v" + std::to_string(type >> 16))
          << l;
    }
  }
  const std::map<std::string, std::string> expected = {
      {"2/10", "42"}, {"2/11", "43"}, {"2/12", "44"}, {"3/1", "5"}, {"3/2", "6"}, {"3/3", "7"}};
  for (const auto& [key, surface] : expected) {
    EXPECT_EQ(seen[key], surface) << key << " in:\n" << joined(lines);
  }
  // A net of its own.
  client_->send("[51] 2 nodes\n");
  const auto net2 = client_->lines_until("[51] OK", kEvent);
  EXPECT_EQ(net2.size(), 4u) << joined(net2);
  EXPECT_EQ(client_->take_bare_lf(), 3) << joined(net2);
}

// A node whose 1017h is 0 (CANopenNode's default) sends its boot-up and no heartbeat. Through
// and past the 3 s after which the gateway took such a node for lost, it answers SDO and the node
// list shows it alive, in its state, with no heartbeat age. Fails when NodeTable watches a node
// from its boot-up (routing/node_table.cpp, due(): without `!r.heartbeat_seen`): state=lost.
TEST_F(RemoteAccess, ANodeWithoutHeartbeatStaysAliveWhileItAnswers) {
  const std::regex quiet_row(
      "\\[[0-9]+\\] node net=2 module=1 gateway=remote-gateway local=12 surface=44 \\S+ \\S+ "
      "state=(\\S+) hb_age_ms=(\\S+) .*");
  const auto check = [&] {
    EXPECT_EQ(ask("0 44 read 0x2003 0 x32"), "0x00C0FFEE") << "the quiet node answers";
    client_->send("[" + std::to_string(++seq_) + "] nodes\n");
    const auto lines = client_->lines_until("[" + std::to_string(seq_) + "] OK", kEvent);
    client_->take_bare_lf();  // the rows' (one answer, framed as help)
    bool found = false;
    for (const auto& l : lines) {
      std::smatch m;
      if (!std::regex_match(l, m, quiet_row)) continue;
      found = true;
      EXPECT_EQ(m[1].str(), "pre-operational") << l;
      EXPECT_EQ(m[2].str(), "-") << l;
    }
    EXPECT_TRUE(found) << joined(lines);
  };
  // Watched over the window in which it used to be lost: every answer along the way counts.
  const auto past_default_lost_after = ready_at_ + 4s;
  do {
    check();
  } while (!HasFailure() && std::chrono::steady_clock::now() < past_default_lost_after);
  check();
}

// help lists the standard commands and the extensions.
TEST_F(RemoteAccess, HelpListsTheCommands) {
  client_->send("help\n[60] set sdo_timeout 1000\n");
  const auto lines = client_->lines_until("[60] ", kEvent);
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines.back(), "[60] OK");
  const std::string text = joined(lines);
  // One answer, one CR LF: help's inner lines end with LF alone, as the reference gateway frames
  // its help, so that cocomm prints all of it (every other answer is checked for CR LF).
  EXPECT_GT(client_->take_bare_lf(), 10) << text;
  for (const char* word : {"r[ead]", "w[rite]", "start", "stop", "preop", "reset", "set", "nodes",
                           "flash", "monitor", "lss"}) {
    EXPECT_NE(text.find(word), std::string::npos) << word << " missing from help:\n" << text;
  }
}

// monitor: frames from a module (translated to surface ids) and from the surface bus.
TEST_F(RemoteAccess, MonitorShowsFramesOfBothDirections) {
  EXPECT_EQ(ask("monitor"), "OK");
  // From module 1's bus: node 10's TPDO1 (0x18A) reaches the surface as node 42's (0x1AA).
  ASSERT_EQ(test::run({"cansend", "vcan1", "18A#0102A5"}).status, 0);
  const std::regex from_module("FRAME [0-9]+ 1 > 1AA#0102A5");
  // From the surface bus (module 0).
  ASSERT_EQ(test::run({"cansend", "vcan0", "123#DEADBEEF"}).status, 0);
  const std::regex from_surface("FRAME [0-9]+ 0 < 123#DEADBEEF");
  bool module_seen = false, surface_seen = false, heartbeat_seen = false;
  const auto deadline = std::chrono::steady_clock::now() + kEvent;
  while (!(module_seen && surface_seen && heartbeat_seen) &&
         std::chrono::steady_clock::now() < deadline) {
    const auto l = client_->line(kEvent);
    if (!l) break;
    module_seen = module_seen || std::regex_match(*l, from_module);
    surface_seen = surface_seen || lower(*l).find("0 < 123#deadbeef") != std::string::npos;
    heartbeat_seen = heartbeat_seen || std::regex_match(*l, std::regex("FRAME [0-9]+ 2 > 705#.*"));
  }
  EXPECT_TRUE(module_seen);
  EXPECT_TRUE(surface_seen);
  EXPECT_TRUE(heartbeat_seen) << "qd-a's heartbeat (surface 5) from module 2";
}

// LSS goes to the module that allows it (lss_module: 1, net 2) and is refused elsewhere.
TEST_F(RemoteAccess, LssOnlyWhereTheModuleAllowsIt) {
  EXPECT_EQ(ask("2 lss_switch_glob 1"), "OK");
  EXPECT_TRUE(candump_->wait_for_line("vcan1 7E5#0401", kEvent)) << candump_->output();
  EXPECT_EQ(ask("2 lss_switch_glob 0"), "OK");
  EXPECT_TRUE(candump_->wait_for_line("vcan1 7E5#0400", kEvent)) << candump_->output();
  const std::string refused = ask("3 lss_switch_glob 1");
  EXPECT_TRUE(refused.starts_with("ERROR:100")) << "module 2 has no LSS: " << refused;
  // Selective switch of node 10 by its identity (the sim's cia301 nodes are LSS slaves), then
  // the inquiries answered by that node alone.
  EXPECT_EQ(ask("2 lss_switch_sel 0x1A2 0x101 0x10001 0xA010"), "OK");
  const std::string id = lower(ask("2 lss_get_node"));
  EXPECT_TRUE(id == "10" || id == "0x0a" || id == "0a") << id;
  const std::string serial = lower(ask("2 lss_inquire_addr 3"));
  EXPECT_TRUE(serial == "40976" || serial == "0x0000a010" || serial == "0xa010") << serial;
  EXPECT_EQ(ask("2 lss_switch_glob 0"), "OK");
}

// --- the canbridge command line ------------------------------------------------------------------

TEST_F(RemoteAccess, CliNodesAndSdo) {
  auto r = cli({"nodes"});
  EXPECT_EQ(r.status, 0) << r.output;
  for (const char* text : {"42", "43", "qd", "cia301"}) {
    EXPECT_NE(r.output.find(text), std::string::npos) << text << " in:\n" << r.output;
  }
  r = cli({"sdo", "read", "--net", "2", "10", "0x2010", "0", "u32"});
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("305419896"), std::string::npos) << r.output;
  r = cli({"sdo", "write", "--net", "2", "10", "0x2007", "0", "i32", "-77"});
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(ask("2 10 r 0x2007 0 i32"), "-77");
  // A domain from a file, checked through the endpoint.
  const auto data = pseudo_random(4096, 7);
  const std::string file = write_file(keys_->path() + "/domain.bin", data);
  r = cli({"sdo", "write", "42", "0x2100", "0", "d", "--file", file});
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(ask("2 10 r 0x2100 0 d"), base64(data));
  // Exit codes: abort 1 (code and text printed), unknown node 3, unreachable endpoint 5.
  r = cli({"sdo", "read", "--net", "2", "10", "0x6666", "0", "u32"});
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(lower(r.output).find("06020000"), std::string::npos) << r.output;
  // Unknown surface node: 3. A module's net reaches unmapped local ids, where nobody answers:
  // timeout, 4.
  r = cli({"sdo", "read", "99", "0x1000", "0", "u32"});
  EXPECT_EQ(r.status, 3) << r.output;
  r = cli({"sdo", "read", "--net", "2", "99", "0x1000", "0", "u32"});
  EXPECT_EQ(r.status, 4) << r.output;
  r = test::run({CANBRIDGE_BIN, "sdo", "read", "42", "0x1000", "0", "u32", "--endpoint",
                 keys_->path() + "/no-such.sock"});
  EXPECT_EQ(r.status, 5) << r.output;
  r = cli({"sdo", "frobnicate"});
  EXPECT_EQ(r.status, 2) << r.output;
}

// cmd sends raw 309-3 lines as cocomm does and prints the answers as they came; a client that
// closes its sending side after its request (printf ... | socat -t 3) still gets the answer.
TEST_F(RemoteAccess, CmdAndAHalfClosingClientGetTheirAnswers) {
  const auto r = cli({"cmd", "42 r 0x2010 0 u32", "[5] 2 10 r 0x6666 0 u32"});
  EXPECT_EQ(r.status, 1) << r.output;  // the abort
  EXPECT_NE(r.output.find("[1] 305419896\n"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("[5] ERROR:0x06020000 #Object does not exist."), std::string::npos)
      << r.output;
  EndpointClient half(socket_path_);
  half.send("[61] 2 10 read 0x1008 0 vs\n");
  half.shutdown_send();
  EXPECT_EQ(half.line(kEvent).value_or("<none>"), "[61] \"canbridge remote cia301 device\"");
  EXPECT_FALSE(half.line(kEvent)) << "the endpoint closes after the last answer";
  EXPECT_TRUE(half.closed());
}

TEST_F(RemoteAccess, CliNmt) {
  struct Case {
    std::vector<std::string> args;
    std::string frame;
  };
  const std::vector<Case> cases = {
      {{"nmt", "stop", "--net", "3", "2"}, "vcan2 000#0202"},
      {{"nmt", "start", "--net", "3", "2"}, "vcan2 000#0102"},
      {{"nmt", "preop", "6"}, "vcan2 000#8002"},
      {{"nmt", "reset-comm", "--net", "3", "2"}, "vcan2 000#8202"},
      {{"nmt", "reset", "--net", "2", "11"}, "vcan1 000#810B"},
      {{"nmt", "start", "--net", "3", "all"}, "vcan2 000#0100"},
      {{"nmt", "preop", "--net", "3", "all"}, "vcan2 000#8000"},
  };
  for (const Case& c : cases) {
    const auto r = cli(c.args);
    EXPECT_EQ(r.status, 0) << c.frame << ": " << r.output;
    EXPECT_TRUE(candump_->wait_for_line(c.frame, kEvent)) << c.frame << "\n" << candump_->output();
  }
}

// The fpga rename (docs/nmt-node-id.md) by set-node-id: boot-up on the new id, the node answers
// under its new surface id, and back.
TEST_F(RemoteAccess, CliSetNodeIdRenamesTheFpgaNode) {
  std::size_t mark = vcan2_->mark();
  auto r = cli({"set-node-id", "--net", "3", "3", "4"});
  EXPECT_EQ(r.status, 0) << r.output;
  // Local 4 is mapped to surface 8: the answer says where the surface reaches the node now.
  EXPECT_NE(r.output.find("renamed to 4; the surface addresses it as node 8"), std::string::npos)
      << r.output;
  EXPECT_TRUE(candump_->wait_for_line("vcan2 000#E00304", kEvent)) << candump_->output();
  EXPECT_TRUE(await(*vcan2_, mark, [](const Frame& f) { return is_heartbeat(f, 4, 0); }));
  EXPECT_EQ(lower(ask("0 8 r 0x2000 0 x32")), "0x0badcafe");
  mark = vcan2_->mark();
  r = cli({"set-node-id", "--net", "3", "4", "3"});
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("as node 7"), std::string::npos) << r.output;
  EXPECT_TRUE(await(*vcan2_, mark, [](const Frame& f) { return is_heartbeat(f, 3, 0); }));
  EXPECT_EQ(lower(ask("0 7 r 0x2000 0 x32")), "0x0badcafe");
}

// A 256 KiB image flashed to qd-a and verified by 1F56h; a corrupt image is refused naming the
// failed step and leaves the node in its loader; flashing a good image again recovers it (16 KiB
// images for these two: the UML guest moves about 10 KiB/s through a block download).
TEST_F(RemoteAccess, CliFlashVerifiesAndACorruptImageLeavesTheLoader) {
  const auto application = pseudo_random(256 * 1024 - 4, 1616);
  const auto image = firmware_image(application);
  const std::string good = write_file(keys_->path() + "/good.img", image);
  const std::string crc = std::to_string(crc32(application));
  const auto small_application = pseudo_random(16 * 1024, 1617);
  const std::string small =
      write_file(keys_->path() + "/small.img", firmware_image(small_application));
  auto corrupt_bytes = firmware_image(small_application);
  corrupt_bytes[10000] ^= 0x40;
  const std::string corrupt = write_file(keys_->path() + "/corrupt.img", corrupt_bytes);

  std::size_t mark = vcan2_->mark();
  auto r = cli({"flash", "--net", "3", "1", good}, kFlash);
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_TRUE(await(*vcan2_, mark, [](const Frame& f) {
    return f == Frame::standard(0x721, {0x00});
  })) << "no loader boot-up";
  EXPECT_TRUE(await(*vcan2_, mark, [](const Frame& f) { return is_heartbeat(f, 1, 0x7F); }));
  EXPECT_EQ(ask("3 1 r 0x1F56 1 u32"), crc) << "the application's identification";

  r = cli({"flash", "--net", "3", "1", corrupt}, kFlash);
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("verify"), std::string::npos) << "names the failed step: " << r.output;
  // Still in the loader: its flash status says no valid program, the application's objects are
  // gone, and the node table says so.
  EXPECT_EQ(ask("3 1 r 0x1F57 1 u32"), "1");
  EXPECT_TRUE(ask("3 1 r 0x1008 0 vs").starts_with("ERROR:0x0602")) << "application object";
  const auto nodes = cli({"nodes"});
  EXPECT_TRUE(std::regex_search(nodes.output, std::regex("loader"))) << nodes.output;

  // Running it again with the good image is safe and brings the application back.
  mark = vcan2_->mark();
  r = cli({"flash", "5", small}, kFlash);  // by surface id this time
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_TRUE(await(*vcan2_, mark, [](const Frame& f) { return is_heartbeat(f, 1, 0x7F); }));
  EXPECT_EQ(ask("3 1 r 0x1F56 1 u32"), std::to_string(crc32(small_application)));
  EXPECT_EQ(ask("3 1 r 0x1008 0 vs"), "\"canbridge remote qd module\"");
}

// The endpoint's flash command with its progress lines.
TEST_F(RemoteAccess, EndpointFlashReportsProgress) {
  const auto application = pseudo_random(8 * 1024, 2626);
  const std::string path = write_file(keys_->path() + "/small.img", firmware_image(application));
  client_->send("[70] 3 2 flash " + path + "\n");
  const auto lines = client_->lines_until("[70] OK", kFlash);
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines.back(), "[70] OK") << joined(lines);
  int progress = 0;
  for (const auto& l : lines) progress += l.starts_with("[70] PROGRESS ") ? 1 : 0;
  EXPECT_GE(progress, 2) << joined(lines);
  EXPECT_EQ(ask("3 2 r 0x1F56 1 u32"), std::to_string(crc32(application)));
}

// dump decodes live frames; --raw prints candump format.
TEST_F(RemoteAccess, CliDumpDecodesLiveFrames) {
  ChildProcess dump({CANBRIDGE_BIN, "dump", "--endpoint", socket_path_, "--module", "1"});
  ChildProcess raw({CANBRIDGE_BIN, "dump", "--endpoint", socket_path_, "--raw"});
  // Heartbeats keep coming: the first ones show the subscriptions are live.
  EXPECT_TRUE(dump.wait_for_line("42", kEvent)) << dump.output();
  EXPECT_TRUE(raw.wait_for_line("72A#", kEvent)) << raw.output();
  // An EMCY of node 10 (module 1) with code 8210h and error register 01h.
  ASSERT_EQ(test::run({"cansend", "vcan1", "08A#1082010000000000"}).status, 0);
  EXPECT_TRUE(dump.wait_for_line("8210", kEvent)) << dump.output();
  EXPECT_TRUE(raw.wait_for_line("0AA#1082010000000000", kEvent)) << raw.output();
  const std::string decoded = dump.output();
  EXPECT_NE(decoded.find("EMCY"), std::string::npos) << decoded;
  EXPECT_EQ(decoded.find("705#"), std::string::npos) << "--module 1 shows module 2:\n" << decoded;
}

// capture -w: a pcap (LINKTYPE_CAN_SOCKETCAN) that tshark opens and dissects as CANopen; -l:
// candump log format. --count ends each capture after that many frames (the nodes' heartbeats
// and the EMCY sent meanwhile).
TEST_F(RemoteAccess, CliCaptureIsReadByTshark) {
  const std::string pcap = keys_->path() + "/capture.pcap";
  const std::string log = keys_->path() + "/capture.log";
  auto r = cli({"capture", "--count", "40", "-w", pcap});
  EXPECT_EQ(r.status, 0) << r.output;
  r = cli({"capture", "--count", "40", "-l", "-w", log});
  EXPECT_EQ(r.status, 0) << r.output;

  const auto shark = test::run({"tshark", "-r", pcap, "-d", "can.subdissector,canopen"}, 60s);
  EXPECT_EQ(shark.status, 0) << shark.output;
  EXPECT_NE(shark.output.find("CANopen"), std::string::npos) << shark.output;
  // Heartbeats of surface nodes, e.g. node 42 (0x72A): "NMT Error Control".
  EXPECT_NE(shark.output.find("NMT Error Control"), std::string::npos) << shark.output;
  EXPECT_EQ(shark.output.find(" CAN "), std::string::npos) << "frames not dissected:\n"
                                                           << shark.output;
  std::ifstream in(log);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_TRUE(
      std::regex_search(text, std::regex("\\([0-9]+\\.[0-9]{6}\\) \\S+ 7(05|06|07|2A|2B)#")))
      << text;
}

}  // namespace
}  // namespace canbridge
