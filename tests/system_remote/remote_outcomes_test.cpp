// Issue 27 in the vcan rig: the command endpoint never reports a failure for work that was done.
// Real processes (surface with its CiA 309-3 endpoint, gateway on vcan1/vcan2, canbridge-sim with
// rig.yaml), faults by signal:
// - the surface SIGSTOPped past a write's answer deadline, then continued: the gateway had done
//   the write and resends its result on the new link; the client gets OK and the node holds it;
// - the gateway SIGKILLed with 16 pipelined writes in flight: every answer is OK and executed,
//   a failure and not executed, or the documented "outcome unknown" (ERROR:108).
// "Executed" is what the module bus shows: the SDO download request the gateway wrote to node 10.
// Each test prints a tally line (answers by kind, executed or not) for the record.
#include <gtest/gtest.h>
#include <signal.h>

#include <filesystem>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <regex>
#include <set>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
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
using test::EndpointClient;
using test::RigProcesses;

constexpr auto kEvent = 10s;
// The surface's answer deadline for a write here: sdo_timeout_ms (200) + the surface's answer
// slack (SurfaceRemoteOptions::answer_slack, 5 s); the stall lasts longer than that.
constexpr auto kDeadline = 5200ms;
constexpr auto kStall = kDeadline + 1500ms;
// Deadline + resend window (SurfaceRemoteOptions::resend_window, 10 s) + room for the UML guest.
constexpr auto kLastAnswer = kDeadline + 10s + 10s;
const std::string kSourceDir = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/system_remote/";
constexpr std::uint32_t kLocalNode = 10;  // module 1 (net 2), cia301, surface id 42

// The gateway's SDO download of `value` to 2003h:00 of node 10 (expedited, 4 bytes).
bool is_write_of(const Frame& f, std::uint32_t value) {
  return f.id == 0x600u + kLocalNode && f.len == 8 && f.data[0] == 0x23 && f.data[1] == 0x03 &&
         f.data[2] == 0x20 && f.data[3] == 0x00 &&
         (f.data[4] | f.data[5] << 8 | f.data[6] << 16 | std::uint32_t(f.data[7]) << 24) == value;
}

// "ERROR:108 #..." (CANopenNode's form) or "ERROR: 108 #...": the 309-3 error code; else nullopt.
std::optional<std::string> error_code_of(std::string_view answer) {
  if (!answer.starts_with("ERROR:")) return std::nullopt;
  answer.remove_prefix(6);
  if (answer.starts_with(" ")) answer.remove_prefix(1);
  return std::string(answer.substr(0, answer.find(' ')));
}

// The census's question to `node` on the module bus, as candump shows it: an SDO upload request
// (40h) of `index`:`subindex`.
std::function<bool(const Frame&)> census_question(std::uint32_t node, std::uint16_t index,
                                                  std::uint8_t subindex) {
  return [=](const Frame& f) {
    return f.id == 0x600u + node && f.len == 8 && f.data[0] == 0x40 &&
           f.data[1] == (index & 0xFF) && f.data[2] == (index >> 8) && f.data[3] == subindex;
  };
}

bool any_failure() {
  return ::testing::UnitTest::GetInstance()->failed_test_count() > 0;
}

// One rig per test: each test breaks a process on purpose.
class RemoteOutcomes : public ::testing::Test {
 protected:
  void SetUp() override {
    keys_ = std::make_unique<test::TempKeyDir>();
    const std::string dir = keys_->path() + "/";
    socket_path_ = dir + "surface.sock";
    const std::string key = keys_->key("remote-gateway.key");
    test::write_remote_rig_configs(*keys_, key, socket_path_, 200);
    std::filesystem::copy_file(kSourceDir + "rig.yaml", dir + "rig.yaml");
    vcan1_ = std::make_unique<BusLog>("vcan1");
    processes_ = std::make_unique<RigProcesses>(
        test::RigOptions{.canbridge = CANBRIDGE_BIN,
                         .sim = CANBRIDGE_SIM_BIN,
                         .link_emulator = {},
                         .link_emulator_args = {},
                         .config_dir = dir,
                         .port_placeholder = "${LINK_PORT}",
                         .surface_name = "remote-surface",
                         .gateway_name = "remote-gateway",
                         .sim_ready = "ready 6 nodes on 2 buses",  // rig.yaml's six, quiet included
                         .event_timeout = kEvent});
    ASSERT_NO_FATAL_FAILURE(processes_->start());
    ASSERT_TRUE(vcan1_->wait_for(
        0,
        [](const Frame& f) {
          return f.id == 0x700u + kLocalNode && f.len == 1 && f.data[0] == 0x7F;
        },
        kEvent))
        << "node 10 does not beat";
    client_ = std::make_unique<EndpointClient>(socket_path_);
  }

  // Asks for network `net`'s node list until a row matches `row` (the surface learns the nodes
  // from the gateway's events) or kEvent passes: whether one did, and the last list.
  std::pair<bool, std::string> poll_nodes(int net, const std::regex& row) {
    std::string all;
    const auto until = std::chrono::steady_clock::now() + kEvent;
    for (int n = 10; std::chrono::steady_clock::now() < until; ++n) {
      const std::string seq = "[" + std::to_string(n) + "]";
      client_->send(seq + " " + std::to_string(net) + " nodes\n");
      all.clear();
      for (const auto& l : client_->lines_until(seq + " OK", kEvent)) all += l + "\n";
      if (std::regex_search(all, row)) return {true, all};
    }
    return {false, all};
  }

  void TearDown() override {
    client_.reset();
    if (processes_) {
      processes_->stop();
      processes_->print_logs(any_failure());
    }
  }

  // What the node holds in 2003h:00, read through the endpoint.
  std::string node_value() {
    const std::string seq = "[100] ";
    const std::string response = client_->ask(seq + "2 10 r 0x2003 0 u32", kEvent);
    EXPECT_TRUE(response.starts_with(seq)) << response;
    return response.starts_with(seq) ? response.substr(seq.size()) : response;
  }

  std::unique_ptr<test::TempKeyDir> keys_;
  std::string socket_path_;
  std::unique_ptr<BusLog> vcan1_;
  std::unique_ptr<RigProcesses> processes_;
  std::unique_ptr<EndpointClient> client_;
};

// Mutations that fail it (checked): Gateway::on_reliable_dropped not queueing the result again
// (the session gives it up as older than reliable_max_age: ERROR 108, the write done); the ledger
// ending a request at its deadline with timed_out instead of waiting, as before issue 27 (ERROR
// 103 with the write confirmed by the node: the invariant fails too).
TEST_F(RemoteOutcomes, ASurfaceStalledPastTheDeadlineStillAnswersTheWriteThatWasDone) {
  const pid_t surface = processes_->surface->pid();
  // The stall must fall between the gateway's write and the surface's answer; when the answer
  // was out first (it lies in the client's socket already), another value tries again.
  std::optional<std::string> answer;
  std::uint32_t value = 0;
  std::size_t value_mark = 0;  // vcan1's log before the write of `value`
  int tries = 0;
  for (std::uint32_t candidate = 999990; candidate < 999999 + 1 && !answer; ++candidate) {
    ++tries;
    const std::size_t mark = vcan1_->mark();
    client_->send("[" + std::to_string(candidate - 999989) + "] 2 10 w 0x2003 0 u32 " +
                  std::to_string(candidate) + "\n");
    ASSERT_TRUE(vcan1_->wait_for(
        mark, [candidate](const Frame& f) { return is_write_of(f, candidate); }, kEvent))
        << "the gateway never wrote " << candidate;
    ASSERT_EQ(::kill(surface, SIGSTOP), 0);
    // Stopped: whatever it answered before is in the socket now; nothing more can come.
    if (auto early = client_->line(100ms)) {
      ASSERT_EQ(::kill(surface, SIGCONT), 0);
      EXPECT_TRUE(early->ends_with("OK")) << *early;
      continue;
    }
    value = candidate;
    value_mark = mark;
    // The fault itself, not a wait for an event: the surface stays frozen past the deadline.
    std::this_thread::sleep_for(kStall);
    ASSERT_EQ(::kill(surface, SIGCONT), 0);
    answer = client_->line(kLastAnswer);
  }
  ASSERT_TRUE(answer) << "no stall fell between write and answer in " << tries << " tries";
  // Executed: node 10 confirmed the download on its bus (the gateway wrote it before the stall).
  const bool executed = vcan1_
                            ->wait_for(
                                value_mark,
                                [](const Frame& f) {
                                  return f.id == 0x580u + kLocalNode && f.len == 8 &&
                                         f.data[0] == 0x60 && f.data[1] == 0x03 &&
                                         f.data[2] == 0x20 && f.data[3] == 0x00;
                                },
                                kEvent)
                            .has_value();
  std::cout << "stalled surface: answer '" << *answer << "', write of " << value << " "
            << (executed ? "confirmed by the node" : "not confirmed") << ", tries " << tries
            << "\n";
  // The invariant: OK and done, or a failure and not done ("outcome unknown" says neither).
  if (answer->ends_with("OK")) {
    EXPECT_TRUE(executed);
  } else if (error_code_of(*answer) != "108") {
    EXPECT_FALSE(executed) << "answered '" << *answer << "' but the node holds the value";
  }
  // And with the resend window, the answer is the gateway's: OK; the node holds the value.
  ASSERT_TRUE(answer->ends_with("OK")) << *answer;
  EXPECT_EQ(node_value(), std::to_string(value));
}

// Mutations that fail it (checked): the ledger ending a request at its deadline with timed_out,
// as before issue 27 (ERROR 103 for a write the bus shows done: 3 of 4 runs, whenever the kill
// falls between a write and its answer); the surface keeping the remote requests it queued for
// the dead process (Surface's discard_queued_remote_payloads): the new process runs one after its
// answer (2 of 2 runs).
TEST_F(RemoteOutcomes, AGatewayKilledWithWritesInFlightLeavesNoFailureThatWasDone) {
  constexpr int kWrites = 16;
  constexpr std::uint32_t kFirst = 5000;
  const std::size_t mark = vcan1_->mark();
  std::string burst;
  for (int i = 0; i < kWrites; ++i) {
    burst +=
        "[" + std::to_string(i + 1) + "] 2 10 w 0x2003 0 u32 " + std::to_string(kFirst + i) + "\n";
  }
  client_->send(burst);
  ASSERT_TRUE(vcan1_->wait_for(
      mark, [](const Frame& f) { return is_write_of(f, kFirst); }, kEvent));
  ASSERT_EQ(::kill(processes_->gateway->pid(), SIGKILL), 0);
  ASSERT_TRUE(processes_->gateway->wait(kEvent));
  std::map<int, std::string> answers;
  while (answers.size() < kWrites) {
    const std::optional<std::string> line = client_->line(kLastAnswer);
    ASSERT_TRUE(line) << answers.size() << " of " << kWrites << " answered";
    const std::size_t close = line->find("] ");
    ASSERT_TRUE(line->starts_with("[") && close != std::string::npos) << *line;
    answers[std::stoi(line->substr(1, close - 1))] = line->substr(close + 2);
  }
  // Executed: the gateway wrote it to the node (the gateway is dead: the log is complete).
  std::set<std::uint32_t> written;
  for (const BusLog::Entry& e : vcan1_->entries(mark)) {
    for (int i = 0; i < kWrites; ++i) {
      if (is_write_of(e.frame, kFirst + i)) written.insert(kFirst + i);
    }
  }
  int ok_executed = 0, failed_not_executed = 0, unknown_executed = 0, unknown_not_executed = 0;
  for (const auto& [seq, answer] : answers) {
    const bool executed = written.contains(kFirst + seq - 1);
    SCOPED_TRACE("[" + std::to_string(seq) + "] " + answer);
    std::cout << "  [" << seq << "] " << answer << (executed ? " (executed)\n" : "\n");
    if (answer == "OK") {
      EXPECT_TRUE(executed) << "OK for a write the node never got";
      ++ok_executed;
    } else if (error_code_of(answer) == "108") {
      ++(executed ? unknown_executed : unknown_not_executed);
    } else {
      EXPECT_FALSE(executed) << "a failure for a write the node got";
      ++failed_not_executed;
    }
  }
  std::cout << "killed gateway, " << kWrites << " writes: OK+executed " << ok_executed
            << ", failed+not executed " << failed_not_executed << ", unknown(108)+executed "
            << unknown_executed << ", unknown(108)+not executed " << unknown_not_executed
            << "; written on the bus " << written.size() << "\n";
  // Some writes were cut off: the kill fell inside the burst, or the test proved nothing.
  EXPECT_LT(ok_executed, kWrites);
  // While the gateway is down the surface still lists its nodes, lost, from its own table, and
  // names the gateway; the answer is OK (issue 28: it was ERROR:201). Asked again until the
  // surface has noticed the dead link (its keepalive), each answer read to its end.
  bool listed = false;
  for (int seq = 90; !listed && seq < 100; ++seq) {
    const std::string tag = "[" + std::to_string(seq) + "] ";
    client_->send(tag + "nodes\n");
    std::vector<std::string> lines;
    while (lines.empty() ||
           !(lines.back().starts_with(tag + "OK") || lines.back().starts_with(tag + "ERROR"))) {
      const std::optional<std::string> line = client_->line(kLastAnswer);
      ASSERT_TRUE(line) << "no end of the nodes answer " << tag;
      lines.push_back(*line);
    }
    if (lines.back() != tag + "OK") continue;  // the link not yet seen down: the gateway was asked
    listed = true;
    std::string all;
    for (const auto& l : lines) all += l + "\n";
    EXPECT_NE(all.find(tag + "gateway name=remote-gateway state=down"), std::string::npos) << all;
    EXPECT_NE(all.find("local=10 surface=42"), std::string::npos) << all;
    EXPECT_EQ(all.find("state=operational"), std::string::npos) << all;
  }
  EXPECT_TRUE(listed) << "nodes never answered OK with the gateway down";
  // A new gateway process (for an orderly stop) must not run what the old one was asked and the
  // surface gave up: no write of the burst reaches the bus after it is up, while node 10 beats
  // twice (the surface's queue goes out the moment the session is up).
  const std::size_t killed_at = vcan1_->mark();
  ASSERT_NO_FATAL_FAILURE(processes_->restart_gateway());
  std::size_t from = vcan1_->mark();
  for (int beat = 0; beat < 2; ++beat) {
    const auto found = vcan1_->wait_for(
        from, [](const Frame& f) { return f.id == 0x700u + kLocalNode && f.len == 1; }, kEvent);
    ASSERT_TRUE(found) << "node 10 does not beat";
    from = found->index + 1;
  }
  for (const BusLog::Entry& e : vcan1_->entries(killed_at)) {
    for (int i = 0; i < kWrites; ++i) {
      EXPECT_FALSE(is_write_of(e.frame, kFirst + i))
          << "write " << i + 1 << " ran in the new gateway process, after its answer";
    }
  }
}

// Issue 28, "loader nodes are listed": a qd node that entered its loader before the gateway
// started announced it to nobody that is still there, and a loader sends nothing on its own. The
// new gateway's census asks the ids it has not heard from (an upload of 1F57h:01, which only the
// loader has) and lists the node in its loader. Fails without the census (Gateway::start() never
// setting census_at_): the node list never shows local 1.
TEST_F(RemoteOutcomes, ANodeWaitingInItsLoaderBeforeTheGatewayStartedIsListed) {
  BusLog vcan2("vcan2");
  // Net 3 node 1 (qd-a) stops its program: its loader announces itself and stays (seeds/003).
  const std::string stop = client_->ask("[1] 3 1 w 0x1F51 1 u8 0", kEvent);
  ASSERT_EQ(stop, "[1] OK");
  ASSERT_TRUE(vcan2.wait_for(
      0, [](const Frame& f) { return f == Frame::standard(0x721, {0x00}); }, kEvent))
      << "no loader boot-up";
  // A new gateway process: it never heard that boot-up.
  ASSERT_EQ(processes_->gateway->stop(), 0) << processes_->gateway->output();
  const std::size_t restarted_at = vcan2.mark();
  ASSERT_NO_FATAL_FAILURE(processes_->restart_gateway());
  ASSERT_TRUE(processes_->gateway->wait_for_line("wait in their loader", kEvent))
      << processes_->gateway->output();
  // The probe on the module bus, as candump would show it: node 1 is asked, and answers with its
  // flash status; node 2, which beats, is not asked.
  const auto asked = [](std::uint32_t node) { return census_question(node, 0x1F57, 1); };
  ASSERT_TRUE(vcan2.wait_for(restarted_at, asked(1), kEvent));
  ASSERT_TRUE(vcan2.wait_for(
      restarted_at,
      [](const Frame& f) {
        return f.id == 0x581 && f.len == 8 && f.data[0] == 0x43 && f.data[1] == 0x57;
      },
      kEvent))
      << "the loader did not answer";
  // The node list shows it in its loader (the surface learns it from the new gateway's events).
  const std::regex loader_row(
      "node net=3 module=2 gateway=remote-gateway local=1 surface=5 \\S+ \\S+ state=loader ");
  const auto [listed, all] = poll_nodes(3, loader_row);
  EXPECT_TRUE(listed) << all << processes_->gateway->output();
  for (const BusLog::Entry& e : vcan2.entries(restarted_at)) {
    EXPECT_FALSE(asked(2)(e.frame)) << "a beating node was asked";
  }
}

// Issue 28, "a node without heartbeat that answers SDO is alive": node 12 ('quiet', 1017h = 0 as
// CANopenNode ships) booted before this gateway process started and has sent nothing since. The
// new gateway's census asks the ids it has not heard from for their device type (1000h:00); node
// 12 answers and is listed alive, state unknown (no heartbeat has told it), with no heartbeat age.
// Fails without the census (Gateway::start() never setting census_at_) or without the node table
// reading SDO answers of nodes it does not know (NodeTable::note_answering): no row for local 12.
TEST_F(RemoteOutcomes, ANodeWithItsHeartbeatOffBeforeTheGatewayStartedIsListedAlive) {
  constexpr std::uint32_t kQuiet = 12;
  ASSERT_EQ(processes_->gateway->stop(), 0) << processes_->gateway->output();
  const std::size_t restarted_at = vcan1_->mark();
  ASSERT_NO_FATAL_FAILURE(processes_->restart_gateway());
  ASSERT_TRUE(processes_->gateway->wait_for_line("for their device type", kEvent))
      << processes_->gateway->output();
  const auto asked = [](std::uint32_t node) { return census_question(node, 0x1000, 0); };
  ASSERT_TRUE(vcan1_->wait_for(restarted_at, asked(kQuiet), kEvent)) << "node 12 was not asked";
  ASSERT_TRUE(vcan1_->wait_for(
      restarted_at,
      [](const Frame& f) {
        return f.id == 0x580u + kQuiet && f.len == 8 && f.data[0] == 0x43 && f.data[1] == 0x00 &&
               f.data[2] == 0x10;
      },
      kEvent))
      << "node 12 did not answer";
  const std::regex alive_row(
      "node net=2 module=1 gateway=remote-gateway local=12 surface=\\d+ \\S+ \\S+ "
      "state=unknown hb_age_ms=- ");
  const auto [listed, all] = poll_nodes(2, alive_row);
  EXPECT_TRUE(listed) << all << processes_->gateway->output();
  EXPECT_EQ(all.find("local=12 surface=44 profile=cia301 kind=- state=lost"), std::string::npos);
  for (const BusLog::Entry& e : vcan1_->entries(restarted_at)) {
    EXPECT_FALSE(asked(kLocalNode)(e.frame)) << "a beating node was asked";
  }
}

}  // namespace
}  // namespace canbridge
