// A simulated CANopen node (the MicroCANopen minimal node of seeds/002): NMT slave, boot-up and
// heartbeat producer, expedited SDO server. A pure core: frames and the time in, frames out.
#pragma once

#include <chrono>
#include <cstdint>
#include <vector>

#include "bridge/canopen/cob_id.hpp"
#include "bridge/canopen/sdo_codec.hpp"
#include "can/frame.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

// Object 1018h.
struct Identity {
  std::uint32_t vendor_id = 0;
  std::uint32_t product_code = 0;
  std::uint32_t revision = 0;
  std::uint32_t serial = 0;
};

struct ResponderConfig {
  canopen::NodeId node_id = 1;             // 1..127
  std::uint32_t device_type = 0x00000191;  // 1000h: CiA 401 generic I/O, as seeds/002 suggests
  Identity identity;
  std::uint16_t heartbeat_ms = 1000;  // initial 1017h; 0 disables the heartbeat
  // seeds/002 (MicroCANopen): no NMT master is present, so the node starts itself and enters
  // operational right after each boot-up instead of waiting in pre-operational.
  bool auto_start = false;
};

class ResponderNode {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // Object indices this node implements.
  static constexpr std::uint16_t kDeviceType = 0x1000;
  static constexpr std::uint16_t kErrorRegister = 0x1001;
  static constexpr std::uint16_t kHeartbeatTime = 0x1017;
  static constexpr std::uint16_t kIdentity = 0x1018;

  // Throws std::invalid_argument for a node id outside 1..127. The node is powered but silent
  // (state boot_up, i.e. initialising) until boot().
  explicit ResponderNode(const ResponderConfig& config);

  canopen::NodeId id() const { return id_; }
  canopen::NmtState state() const { return state_; }
  // 0 when disabled.
  std::chrono::milliseconds heartbeat_period() const;

  // For the device side of a simulation (e.g. setting the error register). A 1017h change made
  // here is not an SDO write: the heartbeat already scheduled still comes at its old time.
  ObjectDictionary& dictionary() { return od_; }
  const ObjectDictionary& dictionary() const { return od_; }

  // Power-on: initialisation, boot-up message, then pre-operational (operational with auto_start).
  std::vector<can::Frame> boot(TimePoint now);
  // Every frame seen on the bus; returns the frames the node sends in reply.
  std::vector<can::Frame> on_frame(const can::Frame& frame, TimePoint now);
  // Whatever is due at `now` (the heartbeat). Calling it early or twice is harmless.
  std::vector<can::Frame> on_tick(TimePoint now);
  // When on_tick next has something to do; TimePoint::max() when nothing is scheduled.
  TimePoint next_deadline() const { return next_heartbeat_; }

 private:
  void initialise(TimePoint now, std::vector<can::Frame>& out);
  void schedule_heartbeat(TimePoint now);
  void handle_nmt(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void handle_sdo(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  can::Frame error_control_frame(canopen::NmtState state) const;

  canopen::NodeId id_;
  bool auto_start_;
  ObjectDictionary od_;
  bool booted_ = false;
  canopen::NmtState state_ = canopen::NmtState::boot_up;
  TimePoint next_heartbeat_ = TimePoint::max();
};

}  // namespace canbridge::sim
