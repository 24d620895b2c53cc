// The gateway role: one reader loop per module bus, COB-IDs translated to the surface network,
// frames batched onto the backbone, and backbone frames routed to the owning module buses.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <memory>
#include <string>
#include <vector>

#include "bridge/backbone_session.hpp"
#include "bridge/cob_id_translator.hpp"
#include "bridge/node_map.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

struct GatewayModule {
  ModuleId id = 0;
  std::unique_ptr<can::Bus> bus;
};

struct GatewayCounters {
  SessionCounters backbone;
  DropCounters translation{};
  std::uint64_t from_buses = 0;       // frames read on module buses
  std::uint64_t to_buses = 0;         // frames handed to module buses
  std::uint64_t dropped_no_link = 0;  // translated frames with no backbone to carry them
  std::uint64_t bus_refused = 0;      // a module bus's transmit queue was full
};

class Gateway {
 public:
  static constexpr std::size_t kDefaultBacklog = 1u << 16;

  // `map` holds the node tables of `modules`, added in the same order.
  Gateway(boost::asio::any_io_executor executor, std::string name, NodeMap map,
          std::vector<GatewayModule> modules, std::size_t max_backlog = kDefaultBacklog);
  ~Gateway();

  void start();
  // Takes over a new backbone connection to the surface (the previous one, if any, is closed).
  void attach(std::shared_ptr<backbone::MessageLink> link);
  void stop();

  GatewayCounters counters() const;
  const std::vector<GatewayModule>& modules() const { return modules_; }
  bool connected() const { return session_ && session_->ready(); }
  std::string stats_line() const;

 private:
  boost::asio::awaitable<void> read_bus(std::size_t module_index);
  void on_backbone_frames(std::uint32_t module_id, std::span<const can::Frame> frames);

  enum Warn : std::size_t { kUnknownModule, kNoLink, kBusRefused, kWarnKinds };

  boost::asio::any_io_executor executor_;
  std::string name_;
  NodeMap map_;
  CobIdTranslator translator_{map_};
  std::vector<GatewayModule> modules_;
  std::size_t max_backlog_;
  std::shared_ptr<BackboneSession> session_;
  GatewayCounters counters_;
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
