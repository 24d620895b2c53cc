#include "sim/emcy_producer.hpp"

#include <algorithm>

#include "canopen/little_endian.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::sim {

using canopen::SdoAbort;

namespace {

constexpr std::uint32_t kEmcyCobIdInvalid = 0x80000000;
constexpr std::uint32_t kEmcyCanIdMask = 0x7FF;
// Bits 11..30: 29-bit identifiers (bit 29) are not simulated, bit 30 is reserved.
constexpr std::uint32_t kUnsupportedEmcyCobIdBits = 0x7FFFF800;

std::uint32_t default_cob_id(canopen::NodeId node) {
  return canopen::cob::emcy + node;
}

can::Frame emcy_frame(std::uint16_t code, std::uint8_t error_register,
                      const EmcyProducer::ManufacturerField& mfr) {
  can::Frame frame;
  frame.len = 8;
  frame.data = {static_cast<std::uint8_t>(code),
                static_cast<std::uint8_t>(code >> 8),
                error_register,
                mfr[0],
                mfr[1],
                mfr[2],
                mfr[3],
                mfr[4]};
  return frame;
}

}  // namespace

EmcyProducer::EmcyProducer(ObjectDictionary& od, canopen::NodeId node, const EmcySpec& spec)
    : od_(od), node_(node) {
  if (od_.find(kErrorRegister, 0) == nullptr) {
    od_.add_unsigned(kErrorRegister, 0, Access::ro, 0, 1);
  }
  od_.add_unsigned(kErrorHistory, 0, Access::rw, 0, 1);
  for (std::size_t k = 1; k <= kHistoryDepth; ++k) {
    od_.add_unsigned(kErrorHistory, static_cast<std::uint8_t>(k), Access::ro, 0, 4);
  }
  od_.add_unsigned(kCobId, 0, Access::rw, default_cob_id(node), 4);
  od_.add_unsigned(kInhibitTime, 0, Access::rw, spec.inhibit_100us, 2);
}

void EmcyProducer::set_node_id(canopen::NodeId node) {
  const OdEntry* entry = od_.find(kCobId, 0);
  if (entry == nullptr) return;
  const std::uint32_t old_default = default_cob_id(node_);
  const auto follow = [&](std::uint32_t cob_id) {
    return (cob_id & kEmcyCanIdMask) == old_default
               ? (cob_id & ~kEmcyCanIdMask) | default_cob_id(node)
               : cob_id;
  };
  const std::uint32_t current = follow(canopen::load_le32(entry->value));
  const std::uint32_t initial = follow(canopen::load_le32(entry->initial));
  // add() makes the value the reset value too; then the current value is put back.
  od_.add_unsigned(kCobId, 0, entry->access, initial, 4);
  od_.set_unsigned(kCobId, 0, current);
  node_ = node;
}

void EmcyProducer::set_enabled(bool on) {
  enabled_ = on;
  if (!on) queue_.clear();
}

std::uint8_t EmcyProducer::error_register() const {
  return static_cast<std::uint8_t>(od_.get_unsigned(kErrorRegister, 0).value_or(0));
}

void EmcyProducer::set_error_register(std::uint8_t value) {
  od_.set_unsigned(kErrorRegister, 0, value);
}

void EmcyProducer::record(std::uint32_t history_entry) {
  for (std::size_t k = kHistoryDepth; k > 1; --k) {
    const auto older = od_.get_unsigned(kErrorHistory, static_cast<std::uint8_t>(k - 1));
    od_.set_unsigned(kErrorHistory, static_cast<std::uint8_t>(k), older.value_or(0));
  }
  od_.set_unsigned(kErrorHistory, 1, history_entry);
  const std::uint32_t count = od_.get_unsigned(kErrorHistory, 0).value_or(0);
  od_.set_unsigned(kErrorHistory, 0,
                   std::min<std::uint32_t>(count + 1, static_cast<std::uint32_t>(kHistoryDepth)));
}

void EmcyProducer::raise(std::uint16_t code, std::uint8_t register_bits,
                         const ManufacturerField& mfr, TimePoint now,
                         std::vector<can::Frame>& out) {
  std::uint8_t reg = error_register() | register_bits;
  if (code != 0) {
    reg |= kGenericError;
    if ((register_bits & ~kGenericError) == 0) generic_error_active_ = true;
    record(code | static_cast<std::uint32_t>(mfr[0] | mfr[1] << 8) << 16);
  }
  set_error_register(reg);
  emit(emcy_frame(code, reg, mfr), now, out);
}

void EmcyProducer::clear_error(std::uint16_t code, std::uint8_t register_bits,
                               const ManufacturerField& mfr, TimePoint now,
                               std::vector<can::Frame>& out) {
  const auto others = static_cast<std::uint8_t>(error_register() & ~register_bits & ~kGenericError);
  const bool generic = generic_error_active_ || others != 0;
  const auto reg = static_cast<std::uint8_t>(others | (generic ? kGenericError : 0));
  set_error_register(reg);
  emit(emcy_frame(code, reg, mfr), now, out);
}

void EmcyProducer::reset_errors(TimePoint now, std::vector<can::Frame>& out) {
  generic_error_active_ = false;
  set_error_register(0);
  emit(emcy_frame(0x0000, 0, {}), now, out);
}

void EmcyProducer::reset() {
  queue_.clear();
  inhibit_end_ = TimePoint::min();
  generic_error_active_ = false;
}

void EmcyProducer::emit(can::Frame frame, TimePoint now, std::vector<can::Frame>& out) {
  if (!enabled_) return;
  // FIFO order: while anything waits, a new EMCY waits behind it.
  if (!queue_.empty() || now < inhibit_end_) {
    if (queue_.size() >= kQueueDepth) {
      ++counters_.dropped;
      return;
    }
    queue_.push_back(frame);
    ++counters_.queued;
    return;
  }
  transmit(frame, now, out);
}

void EmcyProducer::transmit(can::Frame frame, TimePoint now, std::vector<can::Frame>& out) {
  // 1014h is read at sending time: a queued EMCY follows a COB-ID change made meanwhile.
  const std::uint32_t cob_id = od_.get_unsigned(kCobId, 0).value_or(kEmcyCobIdInvalid);
  if ((cob_id & kEmcyCobIdInvalid) != 0) return;
  frame.id = cob_id & kEmcyCanIdMask;
  out.push_back(frame);
  ++counters_.sent;
  const auto inhibit_100us = od_.get_unsigned(kInhibitTime, 0).value_or(0);
  inhibit_end_ = now + std::chrono::microseconds(100 * inhibit_100us);
}

void EmcyProducer::poll(TimePoint now, std::vector<can::Frame>& out) {
  while (!queue_.empty() && now >= inhibit_end_) {
    const can::Frame frame = queue_.front();
    queue_.pop_front();
    transmit(frame, now, out);
  }
}

EmcyProducer::TimePoint EmcyProducer::next_deadline() const {
  return queue_.empty() ? TimePoint::max() : inhibit_end_;
}

std::error_code EmcyProducer::check_write(const OdEntry& entry,
                                          std::span<const std::uint8_t> data) const {
  if (data.size() > 4) return {};
  const std::uint32_t value = canopen::load_le32(data);
  if (entry.index == kErrorHistory && entry.sub == 0) {
    return value == 0 ? std::error_code{} : SdoAbort::value_range;
  }
  if (entry.index == kCobId && entry.sub == 0) {
    const std::uint32_t current = canopen::load_le32(entry.value);
    if (value == current) return {};
    if ((value & kUnsupportedEmcyCobIdBits) != 0) return SdoAbort::value_range;
    const bool valid_now = (current & kEmcyCobIdInvalid) == 0;
    const bool valid_after = (value & kEmcyCobIdInvalid) == 0;
    // CiA 301: bits 0..29 must not change while the EMCY object exists.
    if (valid_now && valid_after && (value & kEmcyCanIdMask) != (current & kEmcyCanIdMask)) {
      return SdoAbort::value_range;
    }
  }
  return {};
}

void EmcyProducer::on_written(const OdEntry& entry, TimePoint /*now*/,
                              std::vector<can::Frame>& /*out*/) {
  if (entry.index == kErrorHistory && entry.sub == 0) {
    for (std::size_t k = 1; k <= kHistoryDepth; ++k) {
      od_.set_unsigned(kErrorHistory, static_cast<std::uint8_t>(k), 0);
    }
  }
}

}  // namespace canbridge::sim
