// The gateway role: one reader loop per module bus, COB-IDs translated to the surface network,
// frames queued in arbitration order for the backbone session to the surface, and backbone frames
// routed to the owning module buses.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <memory>
#include <string>
#include <vector>

#include "backbone/session.hpp"
#include "bridge/backbone_tuning.hpp"
#include "bridge/cob_id_translator.hpp"
#include "bridge/frame_outbox.hpp"
#include "bridge/loop_guard.hpp"
#include "bridge/node_map.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

struct GatewayModule {
  ModuleId id = 0;
  std::unique_ptr<can::Bus> bus;
  bool conflate_pdos = true;
};

struct GatewayCounters {
  backbone::SessionCounters session;
  OutboxCounters outbox;
  DropCounters translation{};
  std::uint64_t from_buses = 0;          // frames read on module buses
  std::uint64_t to_buses = 0;            // frames handed to module buses
  std::uint64_t frames_received = 0;     // frames decoded from the backbone
  std::uint64_t bus_refused = 0;         // a module bus's transmit queue was full
  std::uint64_t malformed_payloads = 0;  // payloads that are not a valid, consistent batch
  std::uint64_t unknown_module = 0;      // batches naming a module this gateway does not serve
  backbone::DeframerCounters framing{};  // CRC-framed links (serial), all links so far
  std::uint64_t echoes_dropped = 0;      // frames this gateway wrote, read back from a bus
};

class Gateway {
 public:
  // `map` holds the node tables of `modules`, added in the same order.
  Gateway(boost::asio::any_io_executor executor, std::string name, NodeMap map,
          std::vector<GatewayModule> modules, BackboneTuning tuning = {});
  ~Gateway();

  void start();
  // Takes over a new backbone link to the surface (a previous one, if any, is closed). Reliable
  // frames not yet acknowledged go again on it, exactly once.
  void attach(std::shared_ptr<backbone::MessageLink> link);
  void stop();

  GatewayCounters counters() const;
  const std::vector<GatewayModule>& modules() const { return modules_; }
  bool connected() const { return stream_.up(); }
  const backbone::PeerStream& stream() const { return stream_; }
  std::string stats_line() const;

 private:
  boost::asio::awaitable<void> read_bus(std::size_t module_index);
  void on_payload(std::span<const std::uint8_t> payload);

  enum Warn : std::size_t { kUnknownModule, kMalformed, kRefused, kBusRefused, kWarnKinds };

  boost::asio::any_io_executor executor_;
  std::string name_;
  NodeMap map_;
  CobIdTranslator translator_{map_};
  std::vector<GatewayModule> modules_;
  std::vector<LoopGuard> loop_guards_;  // one per module bus, same order
  BackboneTuning tuning_;
  backbone::SessionLink::Identity identity_;
  FrameOutbox outbox_;
  backbone::PeerStream stream_;
  std::shared_ptr<backbone::SessionLink> link_;     // the newest link, ready or not
  backbone::DeframerCounters old_links_framing_{};  // of the links before link_
  GatewayCounters counters_;
  v1::Payload inbound_;
  std::vector<can::Frame> decoded_;
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
