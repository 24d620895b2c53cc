#include "sim/pdo_engine.hpp"

#include <algorithm>
#include <set>
#include <stdexcept>
#include <string>

#include "canopen/little_endian.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::sim {

using canopen::SdoAbort;

namespace {

constexpr std::uint32_t kCanIdMask = 0x7FF;
// Bits 11..29 of a COB-ID: 29-bit identifiers (bit 29 = frame type) are not simulated. Bit 30
// (TPDO: no RTR allowed, RPDO: reserved) is accepted and ignored.
constexpr std::uint32_t kUnsupportedCobIdBits = 0x3FFFF800;
constexpr unsigned kMaxPdoBits = 64;
constexpr std::uint8_t kLastSynchronousType = 240;
constexpr std::uint8_t kFirstEventDrivenType = 254;

bool reserved_transmission_type(std::uint32_t type) {
  return type > kLastSynchronousType && type < kFirstEventDrivenType;
}

// CiA 301 7.3.5: identifiers used by NMT, SYNC/EMCY node ids, TIME, SDO, LSS and NMT error
// control of other nodes; a PDO on one of them would disturb those services.
bool restricted_can_id(std::uint32_t id) {
  return id <= 0x07F || (id >= 0x101 && id <= 0x180) || (id >= 0x581 && id <= 0x5FF) ||
         (id >= 0x601 && id <= 0x67F) || (id >= 0x6E0 && id <= 0x6FF) || id >= 0x701;
}

// Bytes an entry can contribute to a PDO: its type's size, or a string's current length.
std::size_t mappable_bytes(const OdEntry& entry) {
  const std::size_t size = fixed_size(entry.type);
  return size != 0 ? size : entry.value.size();
}

bool in_block(std::uint16_t index, std::uint16_t base) {
  return index >= base && index < base + PdoEngine::kMaxPdoNumber;
}

std::uint32_t mapping_entry(const PdoMapEntry& entry) {
  return static_cast<std::uint32_t>(entry.index) << 16 |
         static_cast<std::uint32_t>(entry.sub) << 8 | entry.bits;
}

[[noreturn]] void invalid(const char* what, bool transmit, unsigned number) {
  throw std::invalid_argument(std::string(transmit ? "TPDO " : "RPDO ") + std::to_string(number) +
                              ": " + what);
}

void validate(const ObjectDictionary& od, const std::vector<PdoSpec>& specs, bool transmit) {
  std::set<unsigned> numbers;
  for (const PdoSpec& spec : specs) {
    if (spec.number < 1 || spec.number > PdoEngine::kMaxPdoNumber) {
      invalid("number outside 1..512", transmit, spec.number);
    }
    if (!numbers.insert(spec.number).second) invalid("defined twice", transmit, spec.number);
    if (!spec.cob_id) invalid("no COB-ID", transmit, spec.number);
    if (*spec.cob_id > kCanIdMask)
      invalid("COB-ID is not an 11-bit identifier", transmit, spec.number);
    if (reserved_transmission_type(spec.transmission_type)) {
      invalid("reserved transmission type 241..253", transmit, spec.number);
    }
    unsigned bits = 0;
    for (const PdoMapEntry& map : spec.mapping) {
      const OdEntry* target = od.find(map.index, map.sub);
      if (target == nullptr) invalid("maps a missing object", transmit, spec.number);
      if (map.bits == 0 || map.bits % 8 != 0) {
        invalid("maps a length that is not a whole number of bytes", transmit, spec.number);
      }
      if (map.bits / 8u > mappable_bytes(*target)) {
        invalid("maps more bits than the object holds", transmit, spec.number);
      }
      bits += map.bits;
      if (bits > kMaxPdoBits) invalid("maps more than 64 bits", transmit, spec.number);
    }
  }
}

void add_objects(ObjectDictionary& od, const PdoSpec& spec, bool transmit,
                 PdoEngine::InstallOptions options) {
  const auto offset = static_cast<std::uint16_t>(spec.number - 1);
  const auto communication = static_cast<std::uint16_t>(
      (transmit ? PdoEngine::kTpdoCommunication : PdoEngine::kRpdoCommunication) + offset);
  const auto mapping = static_cast<std::uint16_t>(
      (transmit ? PdoEngine::kTpdoMapping : PdoEngine::kRpdoMapping) + offset);

  od.add_unsigned(communication, 0, Access::constant, transmit ? 5 : 2, 1);
  od.add_unsigned(communication, 1, Access::rw,
                  *spec.cob_id | (spec.enabled ? 0 : PdoEngine::kCobIdInvalid), 4);
  od.add_unsigned(communication, 2, Access::rw, spec.transmission_type, 1);
  if (transmit) {
    od.add_unsigned(communication, 3, Access::rw, spec.inhibit_100us, 2);
    od.add_unsigned(communication, 5, Access::rw, spec.event_timer_ms, 2);
  }

  const Access mapping_access = options.fixed_mapping ? Access::constant : Access::rw;
  od.add_unsigned(mapping, 0, mapping_access, static_cast<std::uint32_t>(spec.mapping.size()), 1);
  for (std::size_t k = 1; k <= PdoEngine::kMaxMappedEntries; ++k) {
    const std::uint32_t value = k <= spec.mapping.size() ? mapping_entry(spec.mapping[k - 1]) : 0;
    od.add_unsigned(mapping, static_cast<std::uint8_t>(k), mapping_access, value, 4);
  }
}

}  // namespace

void PdoEngine::install(ObjectDictionary& od, const std::vector<PdoSpec>& tpdos,
                        const std::vector<PdoSpec>& rpdos, InstallOptions options) {
  // Everything is checked before anything is added, so a refused rig leaves `od` untouched.
  validate(od, tpdos, true);
  validate(od, rpdos, false);
  for (const PdoSpec& spec : tpdos) add_objects(od, spec, true, options);
  for (const PdoSpec& spec : rpdos) add_objects(od, spec, false, options);
}

PdoEngine::PdoEngine(ObjectDictionary& od) : PdoEngine(od, InstallOptions{}) {}

PdoEngine::PdoEngine(ObjectDictionary& od, InstallOptions options) : od_(od), options_(options) {
  for (const auto& [key, entry] : od_.entries()) {
    if (entry.sub != 1) continue;
    if (in_block(entry.index, kTpdoCommunication)) {
      Tpdo tpdo;
      tpdo.number = entry.index - kTpdoCommunication + 1u;
      read_tpdo(tpdo);
      tpdos_.push_back(std::move(tpdo));
    } else if (in_block(entry.index, kRpdoCommunication)) {
      Rpdo rpdo;
      rpdo.number = entry.index - kRpdoCommunication + 1u;
      read_rpdo(rpdo);
      rpdos_.push_back(std::move(rpdo));
    }
  }
}

std::vector<PdoEngine::MappedObject> PdoEngine::read_mapping(std::uint16_t index) const {
  std::vector<MappedObject> mapping;
  const auto count = std::min<std::uint32_t>(od_.get_unsigned(index, 0).value_or(0),
                                             static_cast<std::uint32_t>(kMaxMappedEntries));
  for (std::uint32_t k = 1; k <= count; ++k) {
    const std::uint32_t entry = od_.get_unsigned(index, static_cast<std::uint8_t>(k)).value_or(0);
    mapping.push_back({static_cast<std::uint16_t>(entry >> 16),
                       static_cast<std::uint8_t>(entry >> 8), (entry & 0xFF) / 8});
  }
  return mapping;
}

void PdoEngine::read_tpdo(Tpdo& tpdo) const {
  const auto communication = static_cast<std::uint16_t>(kTpdoCommunication + tpdo.number - 1);
  const std::uint32_t cob_id = od_.get_unsigned(communication, 1).value_or(kCobIdInvalid);
  tpdo.valid = (cob_id & kCobIdInvalid) == 0;
  tpdo.can_id = cob_id & kCanIdMask;
  tpdo.transmission_type =
      static_cast<std::uint8_t>(od_.get_unsigned(communication, 2).value_or(255));
  tpdo.inhibit = std::chrono::microseconds(100 * od_.get_unsigned(communication, 3).value_or(0));
  tpdo.event_timer = std::chrono::milliseconds(od_.get_unsigned(communication, 5).value_or(0));
  tpdo.mapping = read_mapping(static_cast<std::uint16_t>(kTpdoMapping + tpdo.number - 1));
}

void PdoEngine::read_rpdo(Rpdo& rpdo) const {
  const auto communication = static_cast<std::uint16_t>(kRpdoCommunication + rpdo.number - 1);
  const std::uint32_t cob_id = od_.get_unsigned(communication, 1).value_or(kCobIdInvalid);
  rpdo.valid = (cob_id & kCobIdInvalid) == 0;
  rpdo.can_id = cob_id & kCanIdMask;
  rpdo.mapping = read_mapping(static_cast<std::uint16_t>(kRpdoMapping + rpdo.number - 1));
  rpdo.bytes = 0;
  for (const MappedObject& mapped : rpdo.mapping) rpdo.bytes += mapped.bytes;
}

void PdoEngine::restart(Tpdo& tpdo, TimePoint now) const {
  tpdo.last_sent.reset();
  tpdo.inhibit_end = TimePoint::min();
  tpdo.waiting_for_inhibit = false;
  tpdo.syncs_seen = 0;
  const bool timed = tpdo.valid && event_driven(tpdo) && tpdo.event_timer.count() > 0;
  tpdo.event_due = timed ? now + tpdo.event_timer : TimePoint::max();
}

void PdoEngine::start(TimePoint now, std::vector<can::Frame>& out) {
  operational_ = true;
  for (Tpdo& tpdo : tpdos_) {
    read_tpdo(tpdo);
    restart(tpdo, now);
  }
  for (Rpdo& rpdo : rpdos_) read_rpdo(rpdo);
  // Nothing has been sent since start, so every valid event-driven TPDO goes out now.
  poll(now, out);
}

void PdoEngine::stop() {
  operational_ = false;
  for (Tpdo& tpdo : tpdos_) {
    tpdo.waiting_for_inhibit = false;
    tpdo.event_due = TimePoint::max();
  }
}

PdoEngine::PdoData PdoEngine::sample(const Tpdo& tpdo) const {
  // install() holds every mapping to 64 bits, so the data always fits.
  PdoData data;
  for (const MappedObject& mapped : tpdo.mapping) {
    const OdEntry* entry = od_.find(mapped.index, mapped.sub);
    for (std::size_t i = 0; i < mapped.bytes; ++i) {
      // A string shorter than its mapping is padded, as CiA 301 dummy bytes would be.
      data.bytes[data.size++] =
          entry != nullptr && i < entry->value.size() ? entry->value[i] : std::uint8_t{0};
    }
  }
  return data;
}

void PdoEngine::send(Tpdo& tpdo, const PdoData& data, TimePoint now, std::vector<can::Frame>& out) {
  out.push_back(can::Frame::from_span(tpdo.can_id, data.span()));
  tpdo.last_sent = data;
  tpdo.inhibit_end = now + tpdo.inhibit;
  // Any transmission restarts the event timer (CiA 301: it measures the gap since the last TPDO).
  const bool timed = event_driven(tpdo) && tpdo.event_timer.count() > 0;
  tpdo.event_due = timed ? now + tpdo.event_timer : TimePoint::max();
  tpdo.waiting_for_inhibit = false;
  ++counters_.tpdos_sent;
}

void PdoEngine::on_sync(TimePoint now, std::vector<can::Frame>& out) {
  if (!operational_) return;
  for (Tpdo& tpdo : tpdos_) {
    if (!tpdo.valid || tpdo.transmission_type > kLastSynchronousType) continue;
    if (tpdo.transmission_type == 0) {
      const PdoData data = sample(tpdo);
      if (!tpdo.last_sent || *tpdo.last_sent != data) send(tpdo, data, now, out);
    } else if (++tpdo.syncs_seen >= tpdo.transmission_type) {
      tpdo.syncs_seen = 0;
      send(tpdo, sample(tpdo), now, out);
    }
  }
}

PdoEngine::RxResult PdoEngine::on_frame(const can::Frame& frame, TimePoint /*now*/) {
  if (frame.is_extended() || frame.is_remote() || frame.is_error()) return RxResult::not_mine;
  const auto rpdo = std::find_if(rpdos_.begin(), rpdos_.end(), [&](const Rpdo& candidate) {
    return candidate.valid && candidate.can_id == frame.id;
  });
  if (rpdo == rpdos_.end()) return RxResult::not_mine;
  if (!operational_) return RxResult::ignored;
  if (frame.len < rpdo->bytes) {
    ++counters_.rpdo_length_errors;
    return RxResult::length_error;
  }
  std::size_t offset = 0;
  for (const MappedObject& mapped : rpdo->mapping) {
    const OdEntry* entry = od_.find(mapped.index, mapped.sub);
    if (entry != nullptr) {
      const auto* first = frame.data.data() + offset;
      const std::size_t size = fixed_size(entry->type);
      // A number mapped with fewer bytes than its size gets zeros in the bytes not carried.
      std::array<std::uint8_t, 8> value{};
      std::copy_n(first, mapped.bytes, value.begin());
      od_.set_bytes(mapped.index, mapped.sub,
                    std::span(value).first(std::max<std::size_t>(size, mapped.bytes)));
    }
    offset += mapped.bytes;
  }
  ++counters_.rpdos_written;
  return RxResult::written;
}

void PdoEngine::poll(TimePoint now, std::vector<can::Frame>& out) {
  if (!operational_) return;
  for (Tpdo& tpdo : tpdos_) {
    if (!tpdo.valid || !event_driven(tpdo)) continue;
    const PdoData data = sample(tpdo);
    const bool timer_expired = tpdo.event_due <= now;
    const bool changed = !tpdo.last_sent || *tpdo.last_sent != data;
    if (!timer_expired && !changed) {
      // A change that was undone during the inhibit time is no change any more.
      tpdo.waiting_for_inhibit = false;
      continue;
    }
    if (now < tpdo.inhibit_end) {
      tpdo.waiting_for_inhibit = true;
      continue;
    }
    send(tpdo, data, now, out);
  }
}

PdoEngine::TimePoint PdoEngine::next_deadline() const {
  TimePoint next = TimePoint::max();
  if (!operational_) return next;
  for (const Tpdo& tpdo : tpdos_) {
    if (!tpdo.valid || !event_driven(tpdo)) continue;
    // While waiting, the event timer may already have expired: only the inhibit end matters.
    next = std::min(next, tpdo.waiting_for_inhibit ? tpdo.inhibit_end : tpdo.event_due);
  }
  return next;
}

std::error_code PdoEngine::check_cob_id(const OdEntry& entry, std::uint32_t value) const {
  const std::uint32_t current = canopen::load_le32(entry.value);
  if (value == current) return {};
  if ((value & kUnsupportedCobIdBits) != 0) return SdoAbort::value_range;
  const std::uint32_t installed = canopen::load_le32(entry.initial);
  if (options_.fixed_cob_ids) {
    // seeds/001: the identifiers are fixed, but bit 31 may be set or cleared.
    const bool only_bit_31 = (value & ~kCobIdInvalid) == (installed & ~kCobIdInvalid);
    return only_bit_31 ? std::error_code{} : SdoAbort::value_range;
  }
  const bool valid_now = (current & kCobIdInvalid) == 0;
  const bool valid_after = (value & kCobIdInvalid) == 0;
  const std::uint32_t id = value & kCanIdMask;
  // CiA 301: bits 0..29 must not change while the PDO exists.
  if (valid_now && valid_after && id != (current & kCanIdMask)) return SdoAbort::value_range;
  // The installed identifier is allowed even when restricted: the qd set uses SDO images.
  if (valid_after && id != (installed & kCanIdMask) && restricted_can_id(id)) {
    return SdoAbort::value_range;
  }
  return {};
}

std::error_code PdoEngine::check_mapping_entry(std::uint32_t entry, bool transmit) const {
  const auto index = static_cast<std::uint16_t>(entry >> 16);
  const auto sub = static_cast<std::uint8_t>(entry >> 8);
  const auto bits = static_cast<std::uint8_t>(entry);
  if (!od_.has_object(index)) return SdoAbort::no_object;
  const OdEntry* target = od_.find(index, sub);
  if (target == nullptr || bits == 0 || bits % 8 != 0) return SdoAbort::not_mappable;
  if (bits > kMaxPdoBits) return SdoAbort::pdo_too_long;
  if (bits / 8u > mappable_bytes(*target)) return SdoAbort::not_mappable;
  if (transmit && target->access == Access::wo) return SdoAbort::not_mappable;
  if (!transmit && (target->access == Access::ro || target->access == Access::constant)) {
    return SdoAbort::not_mappable;
  }
  return {};
}

std::error_code PdoEngine::check_mapping(const OdEntry& entry, std::uint32_t value,
                                         bool transmit) const {
  if (value == canopen::load_le32(entry.value)) return {};
  const std::uint16_t base = transmit ? kTpdoMapping : kRpdoMapping;
  const auto communication = static_cast<std::uint16_t>(
      (transmit ? kTpdoCommunication : kRpdoCommunication) + (entry.index - base));
  // CiA 301 re-mapping: invalidate the PDO (bit 31), set sub 0 to 0, change the entries, set
  // sub 0 to the count, validate the PDO. Out of order is refused as a device state problem.
  const std::uint32_t cob_id = od_.get_unsigned(communication, 1).value_or(kCobIdInvalid);
  if ((cob_id & kCobIdInvalid) == 0) return SdoAbort::device_state;
  if (entry.sub == 0) {
    if (value > kMaxMappedEntries) return SdoAbort::pdo_too_long;
    unsigned bits = 0;
    for (std::uint32_t k = 1; k <= value; ++k) {
      const std::uint32_t mapped =
          od_.get_unsigned(entry.index, static_cast<std::uint8_t>(k)).value_or(0);
      if (const auto error = check_mapping_entry(mapped, transmit)) return error;
      bits += mapped & 0xFF;
      if (bits > kMaxPdoBits) return SdoAbort::pdo_too_long;
    }
    return {};
  }
  if (od_.get_unsigned(entry.index, 0).value_or(0) != 0) return SdoAbort::device_state;
  return value == 0 ? std::error_code{} : check_mapping_entry(value, transmit);
}

std::error_code PdoEngine::check_write(const OdEntry& entry,
                                       std::span<const std::uint8_t> data) const {
  if (data.size() > 4) return {};
  const std::uint32_t value = canopen::load_le32(data);
  const bool tpdo_communication = in_block(entry.index, kTpdoCommunication);
  if (tpdo_communication || in_block(entry.index, kRpdoCommunication)) {
    switch (entry.sub) {
      case 1:
        return check_cob_id(entry, value);
      case 2:
        return reserved_transmission_type(value) ? SdoAbort::value_range : std::error_code{};
      case 3: {
        if (!tpdo_communication || value == canopen::load_le32(entry.value)) return {};
        // CiA 301: the inhibit time must not change while the PDO exists.
        const std::uint32_t cob_id = od_.get_unsigned(entry.index, 1).value_or(kCobIdInvalid);
        return (cob_id & kCobIdInvalid) == 0 ? SdoAbort::value_range : std::error_code{};
      }
      default:
        return {};
    }
  }
  if (in_block(entry.index, kTpdoMapping)) return check_mapping(entry, value, true);
  if (in_block(entry.index, kRpdoMapping)) return check_mapping(entry, value, false);
  return {};
}

PdoEngine::Tpdo* PdoEngine::find_tpdo(unsigned number) {
  const auto it = std::find_if(tpdos_.begin(), tpdos_.end(),
                               [&](const Tpdo& tpdo) { return tpdo.number == number; });
  return it == tpdos_.end() ? nullptr : &*it;
}

PdoEngine::Rpdo* PdoEngine::find_rpdo(unsigned number) {
  const auto it = std::find_if(rpdos_.begin(), rpdos_.end(),
                               [&](const Rpdo& rpdo) { return rpdo.number == number; });
  return it == rpdos_.end() ? nullptr : &*it;
}

void PdoEngine::on_written(const OdEntry& entry, TimePoint now, std::vector<can::Frame>& out) {
  const bool communication = in_block(entry.index, kTpdoCommunication);
  if (communication || in_block(entry.index, kTpdoMapping)) {
    const unsigned number = entry.index - (communication ? kTpdoCommunication : kTpdoMapping) + 1u;
    if (Tpdo* tpdo = find_tpdo(number)) {
      const bool was_valid = tpdo->valid;
      read_tpdo(*tpdo);
      if (!communication || entry.sub == 2 || was_valid != tpdo->valid) {
        // New mapping, new transmission type, or the PDO (re)appeared: like a fresh start.
        restart(*tpdo, now);
      } else if (entry.sub == 5) {
        const bool timed = tpdo->valid && event_driven(*tpdo) && tpdo->event_timer.count() > 0;
        tpdo->event_due = timed ? now + tpdo->event_timer : TimePoint::max();
      }
    }
  } else if (in_block(entry.index, kRpdoCommunication) || in_block(entry.index, kRpdoMapping)) {
    const std::uint16_t base =
        in_block(entry.index, kRpdoCommunication) ? kRpdoCommunication : kRpdoMapping;
    if (Rpdo* rpdo = find_rpdo(entry.index - base + 1u)) read_rpdo(*rpdo);
  }
  // Whatever was written may be mapped into an event-driven TPDO.
  poll(now, out);
}

std::optional<std::uint32_t> PdoEngine::tpdo_cob_id(unsigned number) const {
  if (number < 1 || number > kMaxPdoNumber) return std::nullopt;
  const auto cob_id =
      od_.get_unsigned(static_cast<std::uint16_t>(kTpdoCommunication + number - 1), 1);
  if (!cob_id || (*cob_id & kCobIdInvalid) != 0) return std::nullopt;
  return *cob_id & kCanIdMask;
}

std::optional<std::uint32_t> PdoEngine::rpdo_cob_id(unsigned number) const {
  if (number < 1 || number > kMaxPdoNumber) return std::nullopt;
  const auto cob_id =
      od_.get_unsigned(static_cast<std::uint16_t>(kRpdoCommunication + number - 1), 1);
  if (!cob_id || (*cob_id & kCobIdInvalid) != 0) return std::nullopt;
  return *cob_id & kCanIdMask;
}

}  // namespace canbridge::sim
