// The PDO side of a simulated CANopen node: the CiA 301 PDO parameter objects, TPDO triggering
// (SYNC, change of state with inhibit time, event timer) and RPDO reception into mapped objects.
// A pure core: the time and frames in, frames out.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <system_error>
#include <vector>

#include "can/frame.hpp"
#include "sim/node_spec.hpp"
#include "sim/object_dictionary.hpp"

namespace canbridge::sim {

class PdoEngine {
 public:
  using TimePoint = std::chrono::steady_clock::time_point;

  // Object index bases (PDO n uses base + n - 1).
  static constexpr std::uint16_t kRpdoCommunication = 0x1400;
  static constexpr std::uint16_t kRpdoMapping = 0x1600;
  static constexpr std::uint16_t kTpdoCommunication = 0x1800;
  static constexpr std::uint16_t kTpdoMapping = 0x1A00;
  static constexpr unsigned kMaxPdoNumber = 512;
  static constexpr std::uint32_t kCobIdInvalid = 0x80000000;  // bit 31: the PDO does not exist
  static constexpr std::size_t kMaxMappedEntries = 8;         // sub-indices 1..8 of the mapping

  struct InstallOptions {
    // QD and FPGA nodes (seeds/001, seeds/000): sub 1 stays writable but only bit 31 may change.
    bool fixed_cob_ids = false;
    // No dynamic mapping: the mapping objects are constant.
    bool fixed_mapping = false;
  };

  // Adds the CiA 301 objects for the specs:
  //   RPDO n: 1400h+n-1 sub 0 = 2 (const), sub 1 COB-ID u32 (bit 31 = disabled), sub 2
  //           transmission type u8; 1600h+n-1 sub 0 count u8, subs 1..8 u32 mapping entries
  //           (index << 16 | sub << 8 | bits).
  //   TPDO n: 1800h+n-1 sub 0 = 5 (const), sub 1 COB-ID, sub 2 transmission type, sub 3 inhibit
  //           time u16 (100 us), sub 5 event timer u16 (ms); sub 4 is reserved and absent, as
  //           CiA 301 asks; 1A00h+n-1 as 1600h.
  // Every spec.cob_id must be set (callers fill the defaults from connection_set.hpp). Throws
  // std::invalid_argument for a missing cob_id or one above 7FFh, a number outside 1..512 or used
  // twice, a reserved transmission type (241..253), a mapping of a missing object, of more bits
  // than the object holds, of a length that is 0 or not a multiple of 8, or of more than 64 bits
  // in all.
  static void install(ObjectDictionary& od, const std::vector<PdoSpec>& tpdos,
                      const std::vector<PdoSpec>& rpdos, InstallOptions options);

  // Takes the PDOs install() added to `od`; `options` must be the ones install() was given, so
  // that check_write() can hold fixed COB-IDs. Nothing is sent until start().
  explicit PdoEngine(ObjectDictionary& od);
  PdoEngine(ObjectDictionary& od, InstallOptions options);

  // Entering operational: re-reads the parameters, arms the event timers; every valid
  // event-driven TPDO sends its current value once, and a type 0 TPDO goes out at the first SYNC.
  void start(TimePoint now, std::vector<can::Frame>& out);
  // Leaving operational: nothing is sent or processed until the next start().
  void stop();

  // SYNC received: type 0 TPDOs whose data changed since they were last sent, and type n
  // (1..240) TPDOs at every n-th SYNC. The inhibit time does not apply to synchronous TPDOs.
  void on_sync(TimePoint now, std::vector<can::Frame>& out);

  enum class RxResult {
    not_mine,      // no valid RPDO has this COB-ID (or not a standard data frame)
    written,       // the mapped objects now hold the frame's bytes
    length_error,  // shorter than the mapping; nothing written (the node sends EMCY 8210h)
    ignored,       // an RPDO's COB-ID, but the node is not operational
  };
  // RPDO reception. Mapped objects are written device-side, without access checks, whatever the
  // transmission type (synchronous RPDOs are not deferred to the next SYNC). Bytes beyond the
  // mapping are accepted, as CiA 301 allows.
  RxResult on_frame(const can::Frame& frame, TimePoint now);

  // Event timers, and change of state of event-driven TPDOs (types 254/255): a TPDO whose mapped
  // bytes differ from the ones it last sent goes out now, or when its inhibit time ends (once,
  // with the value current then). The node calls it after anything that may change values.
  void poll(TimePoint now, std::vector<can::Frame>& out);
  // When poll() next has something to do; TimePoint::max() when nothing is scheduled.
  TimePoint next_deadline() const;

  // The node's write guard forwards here. CiA 301 rules, refusing with:
  //   0x06090030 value range: a COB-ID with bits 11..29 set (no 29-bit ids); a CAN-ID change while
  //     the PDO is and stays valid; a fixed COB-ID whose bits other than 31 change; a restricted
  //     CAN-ID (CiA 301 7.3.5) other than the installed one; transmission type 241..253; a TPDO
  //     inhibit time change while the PDO is valid.
  //   0x08000022 device state: a mapping change while the PDO is valid, or an entry change while
  //     the mapping is enabled (sub 0 != 0).
  //   0x06020000 no object / 0x06040041 not mappable: an entry naming a missing object, a missing
  //     sub-index, a wrong length, a write-only object (TPDO) or a read-only one (RPDO).
  //   0x06040042 PDO too long: sub 0 above 8, an entry above 64 bits, or more than 64 bits in all.
  // Writing the value an entry already holds is always accepted. Constant (fixed) mapping objects
  // are refused by the dictionary itself (0x06010002).
  std::error_code check_write(const OdEntry& entry, std::span<const std::uint8_t> data) const;
  // The node's write listener forwards here: a PDO parameter changed (that PDO is re-read; a TPDO
  // that becomes valid is treated as just started), and any write may change mapped values.
  void on_written(const OdEntry& entry, TimePoint now, std::vector<can::Frame>& out);

  // The CAN identifier of TPDO/RPDO `number`; nullopt if missing or disabled (bit 31).
  std::optional<std::uint32_t> tpdo_cob_id(unsigned number) const;
  std::optional<std::uint32_t> rpdo_cob_id(unsigned number) const;

  struct Counters {
    std::uint64_t tpdos_sent = 0;
    std::uint64_t rpdos_written = 0;
    std::uint64_t rpdo_length_errors = 0;
  };
  const Counters& counters() const { return counters_; }

 private:
  struct MappedObject {
    std::uint16_t index = 0;
    std::uint8_t sub = 0;
    std::size_t bytes = 0;
  };
  // A PDO's data: at most 64 bits (CiA 301), kept in place so that sampling a TPDO for change
  // of state on every poll allocates nothing.
  struct PdoData {
    std::array<std::uint8_t, 8> bytes{};
    std::uint8_t size = 0;
    std::span<const std::uint8_t> span() const { return {bytes.data(), size}; }
    friend bool operator==(const PdoData&, const PdoData&) = default;
  };
  struct Tpdo {
    unsigned number = 0;
    bool valid = false;
    std::uint32_t can_id = 0;
    std::uint8_t transmission_type = 255;
    std::chrono::microseconds inhibit{0};
    std::chrono::milliseconds event_timer{0};
    std::vector<MappedObject> mapping;
    // What went out last; nullopt = nothing since start or enabling, so the next chance sends.
    std::optional<PdoData> last_sent;
    TimePoint inhibit_end = TimePoint::min();
    TimePoint event_due = TimePoint::max();
    bool waiting_for_inhibit = false;
    unsigned syncs_seen = 0;
  };
  struct Rpdo {
    unsigned number = 0;
    bool valid = false;
    std::uint32_t can_id = 0;
    std::vector<MappedObject> mapping;
    std::size_t bytes = 0;
  };

  static bool event_driven(const Tpdo& tpdo) { return tpdo.transmission_type >= 254; }
  void read_tpdo(Tpdo& tpdo) const;
  void read_rpdo(Rpdo& rpdo) const;
  std::vector<MappedObject> read_mapping(std::uint16_t index) const;
  void restart(Tpdo& tpdo, TimePoint now) const;
  PdoData sample(const Tpdo& tpdo) const;
  void send(Tpdo& tpdo, const PdoData& data, TimePoint now, std::vector<can::Frame>& out);
  std::error_code check_cob_id(const OdEntry& entry, std::uint32_t value) const;
  std::error_code check_mapping(const OdEntry& entry, std::uint32_t value, bool transmit) const;
  std::error_code check_mapping_entry(std::uint32_t entry, bool transmit) const;
  Tpdo* find_tpdo(unsigned number);
  Rpdo* find_rpdo(unsigned number);

  ObjectDictionary& od_;
  InstallOptions options_;
  bool operational_ = false;
  std::vector<Tpdo> tpdos_;
  std::vector<Rpdo> rpdos_;
  Counters counters_;
};

}  // namespace canbridge::sim
