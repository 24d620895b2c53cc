// Every SDO request a master sends ends in the answer its node gave or in an abort, before the
// master's own timeout, across backbone cuts (issue 27, item 1): real processes (surface on vcan0,
// gateway on vcan1, canbridge-link-emulator between them on TCP cutting the backbone 5 times for
// 0.7..3 s), the 24 silent devices of rig.yaml, and a master sending 100 requests/s, one
// outstanding per node, each to an object of its own so that every answer, an abort included,
// names its request. The nodes answer each request that reaches them with their own abort
// (object does not exist): that answer is "delivered"; 0x05040000 is the surface's "aborted".
// Asserted: delivered + aborted = sent, none unanswered within the master's timeout, none
// reaching vcan1 twice or after its abort, no answer the master cannot place (late).
// A second scenario cuts for 100..250 ms only: the link is back long before the master's
// timeout, and the answers to the requests in flight at a cut come with the next link (the
// surface's "answers recovered"), instead of aborts. A third cuts silently (the emulator's
// --cut-mode silent: connections stay open, nothing moves), as a blackholed route does.
// CANBRIDGE_SDO_CUTS_SEED (default 5) picks the cuts; the summary line carries the numbers.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/bus_log.hpp"
#include "tests/support/rig_processes.hpp"
#include "tests/system_sdo_noisy/sdo_load_master.hpp"

namespace canbridge {
namespace {

using namespace std::chrono_literals;
using test::SdoRequestRecord;
using Clock = std::chrono::steady_clock;

const std::string kDir = std::string(CANBRIDGE_SOURCE_DIR) + "/tests/system_sdo_noisy/";
constexpr auto kEvent = 20s;  // upper bound of one awaited event in the slow UML guest
constexpr std::uint32_t kLinkDownAbort = 0x05040000;
// The master's SDO timeout: the session's default dead_after_ms (2000) plus a second
// (docs/sdo-timing.md: such a master always gets the answer or the abort). A TCP cut closes
// the connection, so the surface knows of it at once.
constexpr auto kMasterTimeout = 3000ms;
constexpr int kCuts = 5;
constexpr int kCutWindowStartS = 4;  // every process is up by then
constexpr int kCutWindowEndS = 19;
// Arrival times come from two sockets read by two threads of a slow guest.
constexpr auto kClockSlack = 100ms;
constexpr std::uint8_t kLocalNodes = 24;  // rig.yaml: module 1's nodes 1..24 = surface 33..56
constexpr std::uint8_t kSurfaceOffset = 32;

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' ? std::atoi(v) : fallback;
}

// The number after `label` in a counter line ("withdrawn 3"), or -1.
long long counter(const std::string& line, const std::string& label) {
  std::smatch m;
  if (!std::regex_search(line, m, std::regex(label + " ([0-9]+)"))) return -1;
  return std::stoll(m[1].str());
}

long long count_of(const std::string& text, const std::string& needle) {
  long long n = 0;
  for (auto at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) ++n;
  return n;
}

// The cuts of one scenario: how many, their length range (link-emulator --cut-ms), what they do
// to the connections (--cut-mode: close them, or leave them open and silent), the least time
// between two (--cut-gap-ms) and the master's request period.
struct CutProfile {
  int cuts;
  const char* cut_ms;
  const char* mode;
  const char* gap_ms;
  std::chrono::milliseconds period{10};  // the issue's 100 requests/s
};
constexpr CutProfile kLongCuts{kCuts, "700:3000", "close", "1000"};
// Whether a request is in flight at the instant a short cut begins is chance: in a loaded rig
// (ctest -j2), 8 cuts at 100 requests/s once caught none (recovered 0), and 16 cuts recovered
// 1..5 answers. 16 cuts 700 ms apart (the gateway reconnects within 200 ms) at 500 requests/s
// put several requests in flight at each.
constexpr CutProfile kShortCuts{16, "100:250", "close", "700", std::chrono::milliseconds{2}};
constexpr CutProfile kSilentCuts{kCuts, "700:3000", "silent", "1000"};

test::RigOptions rig_options(int seed, CutProfile profile) {
  const std::string window =
      std::to_string(kCutWindowStartS) + ":" + std::to_string(kCutWindowEndS);
  return {
      .canbridge = CANBRIDGE_BIN,
      .sim = CANBRIDGE_SIM_BIN,
      .link_emulator = CANBRIDGE_LINK_EMULATOR_BIN,
      .link_emulator_args = {"--seed", std::to_string(seed), "--cuts", std::to_string(profile.cuts),
                             "--cut-ms", profile.cut_ms, "--cut-gap-ms", profile.gap_ms,
                             "--cut-window-s", window, "--cut-mode", profile.mode},
      .config_dir = kDir,
      .port_placeholder = "${LINK_PORT}",
      .surface_name = "cuts-surface",
      .gateway_name = "cuts-gateway",
      .sim_ready = "ready 24 nodes on 1 buses",
      .event_timeout = kEvent};
}

// What one scenario counted, for the assertions its test adds.
struct CutOutcomes {
  long long cuts = 0;
  long long aborted = 0;
  long long recovered = 0;
};

template <const CutProfile& Profile>
class CutScenario : public ::testing::Test {
 protected:
  void TearDown() override {
    rig.stop();
    rig.print_logs(HasFailure());
  }
  // Runs the master through the cuts and asserts what holds for every cut profile.
  CutOutcomes run_and_check();

  test::RigProcesses rig{rig_options(env_int("CANBRIDGE_SDO_CUTS_SEED", 5), Profile)};
  test::BusLog module_bus{"vcan1"};  // reading long before the traffic
};

template <const CutProfile& Profile>
CutOutcomes CutScenario<Profile>::run_and_check() {
  CutOutcomes outcomes;
  EXPECT_NO_FATAL_FAILURE(rig.start());
  if (::testing::Test::HasFatalFailure()) return outcomes;
  test::SdoLoadOptions load;
  for (std::uint8_t n = 1; n <= kLocalNodes; ++n) load.nodes.push_back(kSurfaceOffset + n);
  load.answer_bound = kMasterTimeout;
  load.numbered_objects = true;
  load.period = Profile.period;
  test::SdoLoadMaster master("vcan0", load);
  master.run(rig.emulator_ready + std::chrono::seconds(kCutWindowEndS + 1));
  EXPECT_NO_FATAL_FAILURE(rig.expect_running());
  const long long cuts = count_of(rig.emulator->output(), " begins");
  rig.stop();

  // What reached the module bus, by request.
  std::map<std::uint32_t, std::vector<Clock::time_point>> executed;
  for (const auto& e : module_bus.entries()) {
    if (e.frame.id <= 0x600 || e.frame.id > 0x600u + kLocalNodes) continue;
    if (auto seq = test::load_request_seq(e.frame, load)) executed[*seq].push_back(e.at);
  }
  long long delivered = 0, aborted = 0, neither = 0, twice = 0, executed_after_abort = 0;
  long long aborted_executed_before = 0, delivered_not_executed = 0;
  std::ostringstream neither_list, after_list;
  for (const SdoRequestRecord& r : master.requests()) {
    const auto it = executed.find(r.seq);
    const std::size_t times = it == executed.end() ? 0 : it->second.size();
    if (times > 1) ++twice;
    const bool link_abort = r.end == SdoRequestRecord::End::abort && r.abort_code == kLinkDownAbort;
    if (r.end == SdoRequestRecord::End::response ||
        (r.end == SdoRequestRecord::End::abort && !link_abort)) {
      ++delivered;  // the node's own answer
      if (times == 0) ++delivered_not_executed;
    } else if (link_abort) {
      ++aborted;
      if (times > 0 && it->second.front() <= r.answered + kClockSlack) ++aborted_executed_before;
      if (times > 0 && it->second.front() > r.answered + kClockSlack) {
        if (++executed_after_abort <= 10) after_list << " #" << r.seq;
      }
    } else {
      if (++neither <= 10) {
        neither_list << " #" << r.seq << " (node " << int{r.node} << ", reached vcan1 " << times
                     << "x)";
      }
    }
  }
  const long long sent = static_cast<long long>(master.requests().size());
  std::cout << "[  rig     ] " << cuts << " cuts: sent " << sent << ", delivered " << delivered
            << ", aborted " << aborted << " (executed before the abort " << aborted_executed_before
            << "), neither " << neither << ", executed after abort " << executed_after_abort
            << ", reached vcan1 twice " << twice << ", late answers " << master.late_answers()
            << ", stray answers " << master.stray_answers() << ", all nodes busy "
            << master.all_busy() << "\n";
  std::cout << "[  rig     ] surface: withdrawn " << counter(rig.surface_final, "withdrawn")
            << ", answers recovered " << counter(rig.surface_final, "answers recovered") << "; "
            << rig.surface_final << "\n";
  std::cout << "[  rig     ] gateway: " << rig.gateway_final << "\n";

  EXPECT_EQ(neither, 0) << "no answer within " << kMasterTimeout.count()
                        << " ms:" << neither_list.str();
  EXPECT_EQ(delivered + aborted, sent);
  EXPECT_EQ(twice, 0);
  EXPECT_EQ(executed_after_abort, 0) << after_list.str();
  EXPECT_EQ(delivered_not_executed, 0);
  EXPECT_EQ(master.late_answers(), 0u) << "answers to requests that had ended";
  EXPECT_EQ(master.stray_answers(), 0u);
  // Every request the surface withdrew at a cut is accounted for once: the one pending at its
  // node got its abort, the others had their answer before; none to a node nobody follows.
  const long long withdrawn = counter(rig.surface_final, "withdrawn"),
                  withdrawn_pending = counter(rig.surface_final, "withdrawn [0-9]+: pending"),
                  answered_before = counter(rig.surface_final, "answered-before"),
                  untracked = counter(rig.surface_final, "untracked");
  EXPECT_GE(withdrawn, 0) << rig.surface_final;
  EXPECT_EQ(withdrawn, withdrawn_pending + answered_before + untracked) << rig.surface_final;
  EXPECT_EQ(untracked, 0) << rig.surface_final;
  // Each pending one got its abort, or its answer from the next link in time.
  EXPECT_LE(withdrawn_pending, aborted + counter(rig.surface_final, "answers recovered"))
      << rig.surface_final;
  // The scenario did what it is for: traffic flowed, and cuts took the link down under it.
  EXPECT_GE(cuts, Profile.cuts - 1);
  EXPECT_GT(delivered, 500);
  outcomes.cuts = cuts;
  outcomes.aborted = aborted;
  outcomes.recovered = counter(rig.surface_final, "answers recovered");
  return outcomes;
}

using SdoAcrossCuts = CutScenario<kLongCuts>;
using SdoAcrossShortCuts = CutScenario<kShortCuts>;

// Cuts of 0.7..3 s: requests queued or sent during a cut are aborted.
TEST_F(SdoAcrossCuts, EveryRequestIsDeliveredOrAbortedBeforeTheMastersTimeout) {
  const CutOutcomes o = run_and_check();
  EXPECT_GT(o.aborted, 0);
}

// Cuts of 100..250 ms, each closing the TCP connections: the surface sees the link go at once,
// and the link is back within a few hundred ms. A request sent before the cut and not yet
// answered may have been executed: its answer comes with the next link, well inside the
// master's timeout. Fails when the surface aborts every request pending at a cut instead of
// waiting for the next link (bridge/sdo_link_guard.hpp: on_gateway_down() ending every wait).
TEST_F(SdoAcrossShortCuts, AnswersOfRequestsInFlightComeWithTheNextLink) {
  const CutOutcomes o = run_and_check();
  EXPECT_GT(o.recovered, 0) << "no answer came with a next link in " << o.cuts << " cuts";
}

using SdoAcrossSilentCuts = CutScenario<kSilentCuts>;

// Silent cuts of 0.7..3 s (a blackholed route): the connections stay open and nothing moves, so
// each end learns of a cut only from its own silence (dead_after_ms, 2 s). Requests the master
// sends meanwhile go into the silent connection; a cut shorter than dead_after delays them, a
// longer one makes the surface abort them, and what the surface sent into the silence reaches
// the gateway after the cut only if the gateway still holds that connection. Asserted as above:
// every request delivered or aborted within the master's timeout, none run after its abort.
// Fails (24 executed after their abort, seed 5) when the surface leaves the SDO requests in the
// unacknowledged messages it resends on the next link (Surface::on_gateway_down's
// withdraw_sdo_requests).
TEST_F(SdoAcrossSilentCuts, NoRequestVanishesOrRunsAfterItsAbort) {
  const CutOutcomes o = run_and_check();
  std::cout << "[  rig     ] silent cuts: aborted " << o.aborted << ", recovered " << o.recovered
            << "\n";
}

}  // namespace
}  // namespace canbridge
