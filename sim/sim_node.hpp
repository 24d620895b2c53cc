// A simulated CANopen node of one of the four kinds in the seeds (microcanopen, qd, fpga,
// cia301), built from a rig file's NodeSpec. A pure core: frames and the time in, frames out.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "sim/node_spec.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

class SdoServer;
class PdoEngine;
class EmcyProducer;
class QdEventFlags;
class RpdopReceiver;
class LssSlave;

class SimNode {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  // Objects every kind implements.
  static constexpr std::uint16_t kDeviceType = 0x1000;
  static constexpr std::uint16_t kErrorRegister = 0x1001;
  static constexpr std::uint16_t kHeartbeatTime = 0x1017;
  static constexpr std::uint16_t kIdentity = 0x1018;
  // qd loader objects (CiA 302 program download): 1F50h:01 image, 1F51h:01 program control,
  // 1F56h:01 application software identification (its CRC-32), 1F57h:01 flash status.
  static constexpr std::uint16_t kProgramData = 0x1F50;
  static constexpr std::uint16_t kProgramControl = 0x1F51;
  static constexpr std::uint16_t kProgramIdentification = 0x1F56;
  static constexpr std::uint16_t kFlashStatus = 0x1F57;
  // Loader boot-up: 0x700 + 0x20 + N (seeds/003), outside the 1..31 range the qd set allows.
  static constexpr std::uint16_t kLoaderBootUpBase = 0x720;
  // EMCY the loader sends when a downloaded image fails its checksum (CiA 301 6200h: user
  // software error).
  static constexpr std::uint16_t kEmcyBadImage = 0x6200;
  // EMCY for an RPDO shorter than its mapping (CiA 301 8210h).
  static constexpr std::uint16_t kEmcyPdoLength = 0x8210;
  // fpga: count of PDO Packets received per RPDO (sub 1..4), readable by expedited SDO so a
  // master can check a transfer without a segmented read.
  static constexpr std::uint16_t kRpdopPacketCount = 0x5F00;

  // Throws std::invalid_argument for a spec the kind cannot honour (node id range, PDO numbers,
  // mappings of missing objects, a qd device type with a profile number).
  explicit SimNode(const NodeSpec& spec);
  ~SimNode();
  SimNode(const SimNode&) = delete;
  SimNode& operator=(const SimNode&) = delete;

  canopen::NodeId id() const { return id_; }
  NodeKind kind() const { return spec_.kind; }
  const std::string& name() const { return spec_.name; }
  canopen::NmtState state() const { return state_; }
  // qd only: the node runs its loader (after a reset, or while no valid application exists).
  bool in_loader() const { return in_loader_; }
  std::chrono::milliseconds heartbeat_period() const;

  // The application's dictionary (for the device side of a simulation and for tests).
  ObjectDictionary& dictionary() { return *od_; }
  const ObjectDictionary& dictionary() const { return *od_; }

  // Power-on: boot-up message(s), then pre-operational (operational with auto_start).
  std::vector<can::Frame> boot(TimePoint now);
  // Every frame seen on the bus; returns the frames the node sends in reply.
  std::vector<can::Frame> on_frame(const can::Frame& frame, TimePoint now);
  // Whatever is due at `now` (heartbeat, PDO timers, traffic, timeouts). Harmless when early.
  std::vector<can::Frame> on_tick(TimePoint now);
  // When on_tick next has something to do; TimePoint::max() when nothing is scheduled.
  TimePoint next_deadline() const;

  // Device-side events, as the node's own hardware would cause them.
  // qd: subsystem 0..11 changed state (state-change EMCY).
  std::vector<can::Frame> flag_subsystem(unsigned subsystem, TimePoint now);
  // fpga: sends `bytes` as a PDO Packet on TPDO `tpdo` (1..4) if it is valid and operational.
  std::vector<can::Frame> send_packet(unsigned tpdo, std::span<const std::uint8_t> bytes,
                                      TimePoint now);
  // fpga: the last PDO Packets received (oldest first, at most 16).
  struct ReceivedPacket {
    unsigned rpdo = 1;
    std::vector<std::uint8_t> bytes;
  };
  const std::deque<ReceivedPacket>& received_packets() const { return received_packets_; }

  struct Counters {
    std::uint64_t boot_ups = 0;
    std::uint64_t loader_entries = 0;
    std::uint64_t images_accepted = 0;
    std::uint64_t images_rejected = 0;
    std::uint64_t renames = 0;
    std::uint64_t rpdo_length_errors = 0;
    std::uint64_t packets_sent = 0;
  };
  const Counters& counters() const { return counters_; }
  // cia301 only (nullptr otherwise): the node's CiA 305 LSS slave. A node-id configured over
  // LSS becomes the node's id at the next NMT reset (node or communication).
  const LssSlave* lss() const { return lss_.get(); }

 private:
  struct Traffic {
    TrafficSpec spec;
    TimePoint next = TimePoint::max();
    std::uint32_t sequence = 0;
  };
  struct PendingWrite {
    bool loader = false;
    std::uint16_t index = 0;
    std::uint8_t sub = 0;
  };

  void build_application(bool keep_process_values);
  void build_loader();
  // What the loader does after its boot-up: run a valid application at once (power-on, unless
  // the rig says wait), or wait for 1F51h / NMT (after the application was told to stop).
  enum class LoaderExit : std::uint8_t { start_valid_application, wait_for_command };
  LoaderExit power_on_exit() const {
    return spec_.loader.wait_for_command ? LoaderExit::wait_for_command
                                         : LoaderExit::start_valid_application;
  }
  void enter_loader(LoaderExit exit, TimePoint now, std::vector<can::Frame>& out);
  void start_application(TimePoint now, std::vector<can::Frame>& out);
  // Rebuilds the application (keeping process values for a communication reset), sends the
  // boot-up and enters pre-operational (operational with auto_start).
  void initialise(bool keep_process_values, TimePoint now, std::vector<can::Frame>& out);
  void set_state(canopen::NmtState state, TimePoint now, std::vector<can::Frame>& out);
  void schedule_heartbeat(TimePoint now);
  void arm_traffic(TimePoint now);

  void handle_nmt(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void handle_loader_nmt(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  bool handle_node_id_command(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void rename(canopen::NodeId next, TimePoint now, std::vector<can::Frame>& out);
  void adopt_lss_node_id();
  // True when an RPDO wrote mapped objects.
  bool handle_pdo_traffic(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out);
  void apply_pending_writes(TimePoint now, std::vector<can::Frame>& out);
  void run_traffic(TimePoint now, std::vector<can::Frame>& out);
  void poll_engines(TimePoint now, std::vector<can::Frame>& out);
  std::error_code check_write(const OdEntry& entry, std::span<const std::uint8_t> data) const;
  can::Frame error_control_frame(canopen::NmtState state) const;

  NodeSpec spec_;
  canopen::NodeId id_;  // the spec's id until an fpga node is renamed (kept across resets)
  bool application_valid_ = true;
  std::uint32_t application_checksum_ = 0;

  std::unique_ptr<ObjectDictionary> od_;
  std::unique_ptr<SdoServer> sdo_;
  std::unique_ptr<PdoEngine> pdo_;
  std::unique_ptr<EmcyProducer> emcy_;
  std::unique_ptr<QdEventFlags> qd_flags_;
  std::unique_ptr<RpdopReceiver> rpdop_;
  std::unique_ptr<ObjectDictionary> loader_od_;
  std::unique_ptr<SdoServer> loader_sdo_;
  std::unique_ptr<LssSlave> lss_;

  bool booted_ = false;
  bool in_loader_ = false;
  canopen::NmtState state_ = canopen::NmtState::boot_up;
  TimePoint next_heartbeat_ = TimePoint::max();
  std::vector<Traffic> traffic_;
  std::vector<PendingWrite> pending_writes_;
  std::deque<ReceivedPacket> received_packets_;
  Counters counters_;
};

}  // namespace canbridge::sim
