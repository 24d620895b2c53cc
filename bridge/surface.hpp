// The surface role: one CAN interface where a master sees every module's nodes, fed by the
// gateways connected over the backbone.
#pragma once

#include <boost/asio/any_io_executor.hpp>
#include <boost/asio/awaitable.hpp>
#include <memory>
#include <string>
#include <vector>

#include "bridge/backbone_session.hpp"
#include "bridge/warn_once.hpp"
#include "can/bus.hpp"

namespace canbridge::bridge {

struct SurfaceCounters {
  SessionCounters backbone;
  std::uint64_t from_bus = 0;         // frames read on the surface bus
  std::uint64_t to_bus = 0;           // frames written to the surface bus
  std::uint64_t dropped_no_link = 0;  // surface frames with no gateway connected
  std::uint64_t bus_refused = 0;      // surface bus transmit queue full
};

class Surface {
 public:
  Surface(boost::asio::any_io_executor executor, std::string name, std::unique_ptr<can::Bus> bus,
          std::size_t max_backlog = 1u << 16);
  ~Surface();

  void start();
  // Takes a newly accepted gateway connection.
  void attach(std::shared_ptr<backbone::MessageLink> link);
  void stop();

  SurfaceCounters counters() const { return counters_; }
  std::size_t gateways_ready() const;
  can::Bus& bus() { return *bus_; }
  std::string stats_line() const;

 private:
  boost::asio::awaitable<void> read_bus();
  void on_gateway_frames(const BackboneSession& from, std::uint32_t module_id,
                         std::span<const can::Frame> frames);

  enum Warn : std::size_t { kUnknownModule, kNoLink, kBusRefused, kWarnKinds };

  boost::asio::any_io_executor executor_;
  std::string name_;
  std::unique_ptr<can::Bus> bus_;
  std::size_t max_backlog_;
  std::vector<std::shared_ptr<BackboneSession>> sessions_;
  SurfaceCounters counters_;
  WarnOnce<kWarnKinds> warn_;
  bool stopped_ = false;
};

}  // namespace canbridge::bridge
