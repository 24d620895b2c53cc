// What an operator's command endpoint asks of the surface: CANopen services (SDO, NMT, firmware
// download, LSS, the node table, a live frame feed) on one node of one 309-3 network, run by the
// gateway that owns the node. The surface implements it over the backbone; tests use fakes.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"

namespace canbridge::bridge {

// A CiA 309-3 network number: 0 is the default network (the surface's one network, addressed
// with surface node ids); a module's own network (local node ids) has the number the surface's
// config gives it (default module id + 1).
using NetworkNumber = std::uint32_t;

struct NetworkInfo {
  NetworkNumber net = 0;
  std::uint32_t module_id = 0;  // 0 for the default network
  std::string gateway;          // "" for the default network
  bool lss = false;             // LSS reaches this module
  bool connected = false;       // its gateway is bound now
};

struct RemoteTarget {
  NetworkNumber net = 0;
  canopen::NodeId node = 0;  // 0 with NMT: every node of the network
};

struct RemoteSdo {
  RemoteTarget target;
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  bool upload = true;
  std::vector<std::uint8_t> data;           // download
  std::chrono::milliseconds timeout{1000};  // per SDO response, as CiA 301's SDO timeout
  std::uint8_t block_size = 0;              // 0: expedited/segmented; 1..127: block transfer
};

enum class NmtCommand : std::uint8_t {
  start = 0x01,
  stop = 0x02,
  preoperational = 0x80,
  reset_node = 0x81,
  reset_communication = 0x82,
};

// Ends of a request that are neither CANopen failures nor std::errc ones.
enum class RemoteEnd {
  // The request may have been executed and no answer can come any more (its gateway went away or
  // restarted without one): not a failure, the operator reads the object back.
  outcome_unknown = 1,
};

inline const std::error_category& remote_end_category() {
  struct Category final : std::error_category {
    const char* name() const noexcept override { return "remote access"; }
    std::string message(int value) const override {
      return value == static_cast<int>(RemoteEnd::outcome_unknown)
                 ? "outcome unknown: it may have been executed"
                 : "remote access error";
    }
  };
  static const Category category;
  return category;
}

inline std::error_code make_error_code(RemoteEnd end) {
  return {static_cast<int>(end), remote_end_category()};
}

// The end of a request: success, or an error. SDO abort codes (canopen::SdoAbort, received or
// decided by the gateway) for CANopen failures; RemoteEnd::outcome_unknown when it may have run
// and no answer can come (bridge/remote_request_ledger.hpp); std::errc for the rest:
// no_such_device_or_address (unknown network or node), host_unreachable (its gateway is not
// connected), timed_out (no result in time, and it did not run or changes nothing),
// operation_canceled (cancel()), permission_denied (not allowed, e.g. LSS on a module without
// it), invalid_argument.
struct RemoteOutcome {
  std::error_code error;
  std::vector<std::uint8_t> data;  // SDO upload: the value; LSS inquiries: the answer
  std::string detail;              // for the operator, e.g. the flash step that failed
  bool ok() const { return !error; }
};

struct FlashProgress {
  std::string step;  // "stop application", "wait loader", "download", "verify", "start", ...
  std::uint64_t bytes_done = 0;
  std::uint64_t bytes_total = 0;
};

struct NodeRow {
  NetworkNumber net = 0;  // the module's network
  std::uint32_t module_id = 0;
  std::string gateway;
  canopen::NodeId local_node = 0;
  canopen::NodeId surface_node = 0;  // 0: unmapped
  std::string profile;
  std::string kind;
  std::uint8_t nmt_state = 0;  // CiA 301 heartbeat byte
  bool in_loader = false;
  bool lost = false;
  std::optional<std::chrono::milliseconds> heartbeat_age;  // unset: never heard
  std::optional<std::uint16_t> last_emcy_code;
  std::uint8_t last_emcy_register = 0;
  std::uint32_t boot_count = 0;
};

// One frame the surface saw on its one network: put on its bus for a gateway's module, or read
// from its bus (from the master).
struct MonitorFrame {
  std::int64_t time_us = 0;     // Unix time
  std::uint32_t module_id = 0;  // 0: from the surface bus (a master)
  bool to_surface_bus = false;  // true: from a gateway's module, toward the master
  can::Frame frame;
};

class RemoteAccess {
 public:
  using RequestId = std::uint64_t;
  using Done = std::function<void(RemoteOutcome)>;

  virtual ~RemoteAccess() = default;

  virtual std::vector<NetworkInfo> networks() const = 0;

  // Every call completes `done` exactly once, later (never inside the call), on the caller's
  // executor. Requests to one node run one at a time, in the order given.
  virtual RequestId sdo(RemoteSdo request, Done done) = 0;
  virtual RequestId nmt(RemoteTarget target, NmtCommand command, Done done) = 0;
  // The fpga's set-node-id (docs/nmt-node-id.md): done once the boot-up on `new_node` is seen.
  virtual RequestId set_node_id(RemoteTarget target, canopen::NodeId new_node, Done done) = 0;
  virtual RequestId flash(RemoteTarget target, std::vector<std::uint8_t> image,
                          std::function<void(const FlashProgress&)> progress, Done done) = 0;
  // CiA 309-3 LSS commands by name (lss_switch_glob, lss_set_node, ...) on network `net`.
  virtual RequestId lss(NetworkNumber net, std::string command, std::vector<std::uint32_t> args,
                        Done done) = 0;
  // The client went away or gave up: a request not yet started is never executed; a running
  // one is aborted on its bus. `done` then completes with operation_canceled (or the real end,
  // had it already ended).
  virtual void cancel(RequestId id) = 0;

  // The node tables of the gateways; `net` 0: all networks. A gateway that is down cannot be
  // asked: its nodes come from the surface's own view of them (the events it sent), each lost.
  virtual void nodes(NetworkNumber net,
                     std::function<void(std::vector<NodeRow>, std::error_code)> done) = 0;

  // A live feed of frames; returns an id for unsubscribe(). The observer is called on the
  // surface's executor, once per frame, and must not block.
  virtual std::uint64_t subscribe(std::function<void(const MonitorFrame&)> observer) = 0;
  virtual void unsubscribe(std::uint64_t id) = 0;
};

}  // namespace canbridge::bridge
