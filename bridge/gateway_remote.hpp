// The services a gateway runs on its module buses for the surface (remote access, issue 16): SDO
// transfers, NMT, set-node-id, the node list, firmware download and LSS, each request answered
// by exactly one RemoteResult. Pure: requests, bus frames, node events and the time in; frames
// for the buses, results and progress out. The gateway writes the frames and sends the payloads.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <unordered_set>
#include <utility>
#include <vector>

#include "bridge/gateway_remote_options.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "canopen/firmware_download.hpp"
#include "canopen/lss_master.hpp"
#include "canopen/sdo_transfer.hpp"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::backbone {
class PayloadSink;
}

namespace canbridge::bridge {

class GatewayRemote {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  struct Module {
    ModuleId id = 0;
    bool lss = false;    // LSS reaches this module's bus
    bool census = true;  // census() asks its silent ids
  };
  // True while a master on the surface (through the tunnel) has an SDO transfer open with the
  // node (ModuleSdoTracking): the gateway's own transfer waits (first come owns the channel).
  using MasterBusy = std::function<bool(std::size_t module_index, canopen::NodeId local)>;

  struct BusFrames {
    std::size_t module_index = 0;
    std::vector<can::Frame> frames;
  };

  struct Counters {
    std::uint64_t requests = 0;          // requests taken (duplicates not counted)
    std::uint64_t census_questions = 0;  // ask_silent_nodes() questions (not in `requests`)
    std::uint64_t census_yielded = 0;    // ... ended unanswered for a surface master (yield_census)
    std::uint64_t census_late_answers = 0;  // ... whose answer came after all: taken, not forwarded
    std::uint64_t failed = 0;               // results with an abort code (cancelled ones included)
    std::uint64_t cancelled = 0;            // answered "cancelled"
    std::uint64_t duplicates = 0;           // repeated request ids: answered with nothing
    std::uint64_t waited_for_master = 0;    // transfers that waited for a master's transfer
    std::uint64_t sdo_frames_taken = 0;     // node responses that went to the runner
    // Results the session gave up for their age (a long cut or stall), queued again: the
    // surface still waits for them (bridge/remote_request_ledger.hpp).
    std::uint64_t results_resent = 0;
  };

  // Flash progress goes at most this often (and at every step change): it is unreliable anyway.
  static constexpr std::chrono::milliseconds kProgressEvery{250};
  // Ids the gateway remembers having answered (a repeated one is never run twice).
  static constexpr std::size_t kRememberedIds = 1024;

  // `map` and `table` are the gateway's (they must outlive this); `modules` in the map's order.
  GatewayRemote(const NodeMap& map, const NodeTable& table, std::vector<Module> modules,
                GatewayRemoteOptions options, MasterBusy master_busy);

  void on_request(const v1::RemoteRequest& request, TimePoint now);
  void on_cancel(const v1::RemoteCancel& cancel, TimePoint now);
  // Every frame read on module `module_index`'s bus. True when it is the node's SDO response to
  // a transfer the gateway runs: it belongs to the runner and must not reach the surface.
  bool on_bus_frame(std::size_t module_index, const can::Frame& frame, TimePoint now);
  // Node table events (after the gateway followed renames): a boot-up confirms set-node-id.
  void on_node_event(const NodeEvent& event, TimePoint now);
  // Starts what waits and can run now (a master's transfer ended), ends what timed out.
  void tick(TimePoint now);
  std::optional<TimePoint> next_deadline() const;

  // True while the gateway runs a transfer on node `local`'s default SDO channel: an SDO request
  // from the surface master to it must not reach the bus (the gateway answers it with an abort).
  bool transferring(std::size_t module_index, canopen::NodeId local) const;

  // A surface master's frame on its way to module `module_index`'s bus, when it is an SDO request
  // to a node the gateway runs its own transfer with (transferring): a census question gives way
  // (yield_census) and the frame passes; any other transfer refuses it, answered toward the
  // surface as if by the node with abort 0x08000021 (unless it is the master's own abort, which
  // needs no answer). Never written, a refused request cannot cross the gateway's transfer.
  struct MasterCollision {
    bool refused = false;
    std::optional<can::Frame> abort;  // to the surface, as the node's answer
  };
  MasterCollision on_master_frame(std::size_t module_index, const can::Frame& local);

  // The census's question to a node the gateway has not heard from since it started: one that
  // booted before it and stays silent (a loader never sends on its own; an application with its
  // heartbeat off, CANopenNode's default, sends nothing after its boot-up).
  enum class CensusQuestion : std::uint8_t {
    // qd: the flash probe's upload of 1F57h:01 (a loader answers it; an application says the
    // object does not exist, and that answer lists it too: NodeTable reads every SDO answer).
    in_loader,
    // Other profiles: an upload of the device type, 1000h:00, which every CiA 301 node has.
    present,
  };
  // Asks each of `locals` on module `module_index` `question`. Each waits for a master's open
  // transfer with the node, as any transfer of the gateway does, and gives up after `timeout`.
  // The answers cross the module bus, where the node table hears them; the loaders that
  // answered also come out of take_found_in_loader(). Nothing reaches the surface.
  void ask_silent_nodes(std::size_t module_index, const std::vector<canopen::NodeId>& locals,
                        CensusQuestion question, std::chrono::milliseconds timeout, TimePoint now);
  // The start-up census, run once the nodes with a heartbeat have all been heard: on each module
  // with `census` on, the mapped ids the node table does not know are asked their profile's
  // question (in_loader on qd, present otherwise). What each module asked, for the log.
  struct CensusAsked {
    std::size_t module_index = 0;
    std::size_t ids = 0;
    CensusQuestion question = CensusQuestion::present;
  };
  std::vector<CensusAsked> census(std::chrono::milliseconds timeout, TimePoint now);
  struct FoundInLoader {
    std::size_t module_index = 0;
    canopen::NodeId local = 0;
  };
  std::vector<FoundInLoader> take_found_in_loader() { return std::exchange(found_in_loader_, {}); }
  // A surface master's SDO request to `local` met the gateway's own transfer with it: true when
  // that transfer is a census question, which then ends at once, unanswered and with nothing
  // written (an abort frame would end the master's transfer at the node too), so the master's
  // request goes to the node. The census only asks: it never makes a master see a collision
  // (0x08000021) from a node that may not even exist. False for any other transfer.
  // The node may still answer the question (it was on the bus): until the question's own
  // deadline, an SDO answer of the node naming the question's object is taken here, so that the
  // master gets only the answer to its own request (counted as census_late_answers).
  bool yield_census(std::size_t module_index, canopen::NodeId local);

  // Output, taken by the gateway.
  std::vector<BusFrames>& bus_frames() { return bus_frames_; }
  bool has_results() const { return !results_.empty(); }
  const v1::RemoteResult& front_result() const { return results_.front(); }
  void pop_result() { results_.pop_front(); }
  // A result sent before and given up by the session (too old): sent again, after what waits.
  void resend_result(v1::RemoteResult result) {
    results_.push_back(std::move(result));
    ++counters_.results_resent;
  }
  // The latest progress of each request that made some since the last call (unreliable).
  std::vector<v1::RemoteProgress> take_progress();
  // Hands `sink` the results (reliable, in order, while it has room) and then the latest
  // progress of each request (unreliable: one that finds no room is replaced by the next).
  void produce(backbone::PayloadSink& sink);

  const Counters& counters() const { return counters_; }
  std::size_t pending() const;  // requests queued or running

 private:
  struct Job {
    v1::RemoteRequest request;
    std::optional<TimePoint> blocked_since;  // waiting for a master's transfer to end
  };
  struct Running {
    std::uint64_t id = 0;
    std::optional<canopen::SdoTransfer> sdo;         // SDO (the default channel is the runner's)
    canopen::NodeId new_node = 0;                    // set-node-id: the id whose boot-up confirms
    TimePoint deadline = TimePoint::max();           // set-node-id: the boot-up's
    std::optional<canopen::FirmwareDownload> flash;  // flash (also owns the SDO channel)
    std::optional<canopen::LssMaster> lss;  // LSS: the module's lane (node 0), answers on 0x7E4
    bool lss_inquiry = false;               // LSS: the answer carries a value
    canopen::FirmwareProgress reported{};   // flash (SDO: bytes_done only): last reported
    TimePoint reported_at{};
    bool uses_channel() const { return sdo.has_value() || flash.has_value(); }
    TimePoint next_deadline() const {
      return sdo ? sdo->deadline() : flash ? flash->deadline() : lss ? lss->deadline() : deadline;
    }
  };
  struct Lane {
    std::deque<Job> queue;
    std::optional<Running> running;
  };
  using LaneKey = std::pair<std::size_t, canopen::NodeId>;

  // A request taken from the surface, or a probe (ask_silent_nodes): validated, queued on its
  // node's lane, started when it can run.
  void take(const v1::RemoteRequest& request, TimePoint now);
  // The one result of request `id`, queued for the surface.
  void push_result(std::uint64_t id, std::uint32_t abort_code, std::string detail,
                   std::string data = {});
  void answer(std::uint64_t id, std::uint32_t abort_code, std::string detail,
              std::string data = {});
  // A running SDO transfer's progress, at most every kProgressEvery (unreliable, latest wins).
  void report_sdo_progress(Running& r, TimePoint now);
  void answer_nodes(const v1::RemoteRequest& request, TimePoint now);
  void write_nmt(std::size_t module_index, std::uint8_t command, canopen::NodeId node);
  std::vector<can::Frame>& frames_for(std::size_t module_index);
  // Starts the head of every idle lane that can run (repeatedly: NMT ends at once).
  void pump(TimePoint now);
  // Starts `job` on an idle lane; false when it must wait (a master's transfer is open).
  bool start(const LaneKey& key, Lane& lane, Job& job, TimePoint now);
  void finish_sdo(Lane& lane);
  void finish_lss(Lane& lane);
  // The LSS service a 309-3 command names; nullopt (with `why`) for an unknown or bad one.
  std::optional<canopen::LssMaster> lss_service(const v1::LssOp& op,
                                                std::chrono::milliseconds timeout, bool& inquiry,
                                                std::string& why) const;
  // After any input to a running flash: progress (at most every kProgressEvery, and at each
  // step change) or its one result.
  void after_flash(Lane& lane, TimePoint now);
  void remember(std::uint64_t id);
  bool known_id(std::uint64_t id) const;
  std::chrono::milliseconds timeout_of(const v1::RemoteRequest& request) const;

  const NodeMap* map_;
  const NodeTable* table_;
  std::vector<Module> modules_;
  GatewayRemoteOptions options_;
  MasterBusy master_busy_;
  std::map<LaneKey, Lane> lanes_;
  std::vector<BusFrames> bus_frames_;
  std::deque<v1::RemoteResult> results_;
  std::map<std::uint64_t, v1::RemoteProgress> progress_;
  std::unordered_set<std::uint64_t> finished_;
  std::deque<std::uint64_t> finished_order_;  // oldest first, at most kRememberedIds
  std::size_t flashes_running_ = 0;           // bus frames are shown to every running flash
  // ask_silent_nodes(): its requests' ids (kProbeIdBit set: a surface request carrying it is
  // refused by on_request), the node each asks and what.
  static constexpr std::uint64_t kProbeIdBit = std::uint64_t{1} << 63;
  struct CensusProbe {
    FoundInLoader node;
    CensusQuestion question = CensusQuestion::present;
  };
  std::uint64_t probes_sent_ = 0;
  std::map<std::uint64_t, CensusProbe> probes_;
  // Questions that gave way (yield_census): the object each asked and until when its answer may
  // come. An answer naming it is the census's, never the master's.
  struct YieldedQuestion {
    canopen::sdo::Multiplexer object;
    TimePoint until{};
  };
  std::map<LaneKey, YieldedQuestion> yielded_;
  // True when `frame` (an SDO answer of `node`) answers a question that gave way: taken.
  bool take_late_census_answer(std::size_t module_index, canopen::NodeId node,
                               const can::Frame& frame, TimePoint now);
  std::vector<FoundInLoader> found_in_loader_;
  Counters counters_;
};

}  // namespace canbridge::bridge
