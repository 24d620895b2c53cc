// The gateway role: one reader loop per module bus, COB-IDs translated to the surface network,
// frames queued in arbitration order for the backbone session to the surface, and backbone frames
// routed to the owning module buses.
#pragma once

#include <array>
#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <chrono>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/backbone_tuning.hpp"
#include "bridge/bus_writer.hpp"
#include "bridge/deadline_driver.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/gateway_counters.hpp"
#include "bridge/gateway_node_events.hpp"
#include "bridge/gateway_pdop_work.hpp"
#include "bridge/gateway_remote.hpp"
#include "bridge/gateway_remote_options.hpp"
#include "bridge/gateway_statistics.hpp"
#include "bridge/line_loss_counter.hpp"
#include "bridge/loop_guard.hpp"
#include "bridge/module_sdo_tracking.hpp"
#include "bridge/node_report_queue.hpp"
#include "bridge/role_statistics.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"
#include "routing/cob_id_translator.hpp"
#include "routing/node_map.hpp"
#include "routing/node_table.hpp"

namespace canbridge::bridge {

struct GatewayModule {
  ModuleId id = 0;
  std::unique_ptr<can::Bus> bus;
  bool conflate_pdos = true;
  bool lss = false;  // LSS reaches this module (at most one module of a gateway)
  std::optional<std::chrono::milliseconds> heartbeat_lost_after{};  // unset: 3 x observed interval
  bool census = true;  // ask the silent mapped ids 2 s after start (GatewayRemote::census)
  // pdop modules (docs/pdop.md): TPDOP fragments are reassembled and cross as one packet each
  // (false: forwarded frame by frame, as on any other module), RPDOP packets from the surface
  // are segmented toward the node with its flow control. Ignored on other profiles.
  bool reassemble_pdop = true;
  PdopReassemblerOptions pdop_reassembly{};
  PdopSegmenterOptions pdop_segmentation{};
};

class Gateway {
 public:
  // `map` holds the node tables of `modules`, added in the same order.
  Gateway(boost::asio::any_io_executor executor, std::string name, NodeMap map,
          std::vector<GatewayModule> modules, BackboneTuning tuning = {},
          GatewayRemoteOptions remote = {});
  ~Gateway();

  void start();
  // Takes over a new backbone link to the surface (a previous one, if any, is closed). Reliable
  // frames not yet acknowledged go again on it, exactly once.
  void attach(std::shared_ptr<backbone::MessageLink> link);
  void stop();
  // Called once when the gateway stops itself because one of its loops ended or threw (a bus
  // gone for good, a bug): the process shuts down in order and exits non-zero.
  void on_failure(std::function<void(const std::string& reason)> handler) {
    on_failure_ = std::move(handler);
  }
  // Why the gateway stopped itself; empty while it has not.
  const std::string& failure() const { return failure_; }

  GatewayCounters counters() const;
  const std::vector<GatewayModule>& modules() const { return modules_; }
  bool connected() const { return stream_.up(); }
  const backbone::PeerStream& stream() const { return stream_; }
  const NodeTable& node_table() const { return node_table_; }
  std::string stats_line() const;
  // The typed snapshot behind `canbridge stats` and /metrics (bridge/role_statistics.hpp).
  RoleStatistics statistics() const;
  // Everything the two above say, gathered once (bridge/gateway_statistics.hpp).
  GatewayStatsSnapshot stats_snapshot() const;

 private:
  backbone::PeerStream::Handlers stream_handlers();
  // Module `m`'s node table, bus writer, announcement and LSS route.
  void add_module_bus(std::size_t m);
  // Returns the bus's error when the bus ends (closed, or gone for good).
  boost::asio::awaitable<std::error_code> read_bus(std::size_t module_index);
  // One batch read on a module bus, in bus order: echoes dropped, the node table fed, PDO
  // Packets reassembled, everything else queued for the surface.
  void on_bus_batch(std::size_t module_index, std::span<const can::Frame> batch);
  // True (counted) when `frame` is one this gateway wrote to the bus, read back.
  bool drop_echo(std::size_t module_index, const can::Frame& frame,
                 LoopGuard::Clock::time_point now);
  // The node table (and the live map's renames) see every frame of a module bus first.
  void note_bus_frame(std::size_t module_index, const can::Frame& frame,
                      LoopGuard::Clock::time_point now);
  // Translated, SDO values rewritten, into the outbox (the link may be down).
  void queue_for_surface(std::size_t module_index, const can::Frame& frame,
                         LoopGuard::Clock::time_point now);
  // Every loop the gateway spawns ends here: one that ends while the gateway runs stops it.
  void on_task_end(const std::string& task, const std::string& why);
  // Frames one module's BusWriter put on its bus.
  void on_written(std::size_t module_index, std::span<const can::Frame> frames);
  // Input from the surface waits while any module bus is backed up (BusWriteQueue::backlogged).
  void on_backlog_changed();
  void on_payload(std::span<const std::uint8_t> payload);
  // The decoded frames of one batch from the surface, translated to the buses of the modules
  // they address (only module `only`'s when set), SDO values rewritten.
  void write_to_buses(std::optional<std::size_t> only);
  // The surface declared the link dead (its master saw every SDO transfer aborted).
  void on_link_dead();
  // A reliable payload the session gave up on: a remote result goes again, frames are counted
  // by why.
  void on_payload_dropped(const std::string& payload, backbone::ReliableDrop why);
  // Node table events go to the surface as reliable payloads; the deadline driver re-arms.
  void after_node_input();
  // The input's node events (renames followed, claims re-encoded) to the SDO tracking, the
  // remote services and the surface's report queue.
  void queue_node_events();
  // A surface process the gateway has not reported to (the first ever, a restarted one) learns
  // every node the table knows, in their states now, from these events: behind what is queued.
  void queue_node_snapshot(const v1::Hello& surface);
  // Said once when the bound on queued node events dropped some.
  void warn_events_dropped();
  void produce(backbone::PayloadSink& sink);

  // Hands the PDOP work's fragments to their modules' BusWriters, each batch whole.
  void write_pdop_frames();
  // Remote services: their frames to the buses, the driver re-armed, results to the stream, the
  // loaders the census found to the node table.
  void after_remote_input();
  // The census (GatewayRemote::census), logged per module.
  void ask_silent_nodes(DeadlineDriver::TimePoint now);
  // A surface master's SDO request to a node the gateway runs its own transfer with: not
  // written; answered toward the surface with abort 0x08000021 (counted). True when refused.
  bool refuse_colliding_sdo(std::size_t module_index, const can::Frame& local);

  enum Warn : std::size_t {
    kUnknownModule,
    kMalformed,
    kRefused,
    kBusRefused,
    kEventsDropped,
    kSdoCollision,
    kWarnKinds
  };

  boost::asio::any_io_executor executor_;
  std::string name_;
  NodeMap map_;
  CobIdTranslator translator_{map_};
  std::vector<GatewayModule> modules_;
  std::vector<LoopGuard> loop_guards_;               // one per module bus, same order
  std::vector<std::unique_ptr<BusWriter>> writers_;  // one per module bus, same order
  ModuleSdoTracking sdo_{map_};                      // every node's default SDO channel, per module
  NodeTable node_table_;
  GatewayRemote remote_;  // services the surface asks for (SDO, NMT, flash, nodes)
  // One timer for every core with deadlines: the node table and the PDOP work.
  DeadlineDriver deadlines_;
  GatewayNodeEvents node_events_;  // of the input being handled
  NodeReportQueue reports_;        // node events and snapshots waiting for the link
  // The surface process (its hello's session id) the node table was last sent to; 0: none yet.
  std::uint64_t snapshot_surface_ = 0;
  // When the census runs (once, kCensusAfter after start).
  std::optional<DeadlineDriver::TimePoint> census_at_;
  GatewayPdopWork pdop_;
  BackboneTuning tuning_;
  backbone::SessionLink::Identity identity_;
  FrameOutbox outbox_;
  backbone::PeerStream stream_;
  backbone::SessionLogMemory session_log_;
  LineLossCounter line_loss_;
  std::shared_ptr<backbone::SessionLink> link_;     // the newest link, ready or not
  backbone::DeframerCounters old_links_framing_{};  // of the links before link_
  std::uint64_t old_links_tx_bytes_ = 0;
  backbone::LinkCounters old_links_{};  // rx bytes and messages, writes: of the links before link_
  GatewayCounters counters_;
  v1::Payload inbound_;
  std::vector<can::Frame> decoded_;
  std::vector<std::vector<can::Frame>> to_bus_;  // per module bus: its frames of one batch
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
  std::function<void(const std::string&)> on_failure_;
  std::string failure_;
};

}  // namespace canbridge::bridge
