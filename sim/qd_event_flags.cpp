#include "sim/qd_event_flags.hpp"

#include <algorithm>

namespace canbridge::sim {

namespace {

constexpr std::uint16_t kFlagMask = 0x0FFF;
constexpr std::int64_t kMaxHoldoffMs = 0xFFFF;

}  // namespace

QdEventFlags::QdEventFlags(ObjectDictionary& od, EmcyProducer& emcy,
                           std::chrono::milliseconds holdoff)
    : od_(od), emcy_(emcy) {
  const auto holdoff_ms = std::clamp<std::int64_t>(holdoff.count(), 0, kMaxHoldoffMs);
  od_.add_unsigned(kEventResetRegister, 0, Access::rw, 0, 2);
  od_.add_unsigned(kHoldoffTime, 0, Access::rw, static_cast<std::uint32_t>(holdoff_ms), 2);
}

std::chrono::milliseconds QdEventFlags::holdoff() const {
  // Read from the dictionary each time, so an NMT reset that restores 2F01h takes effect.
  return std::chrono::milliseconds(od_.get_unsigned(kHoldoffTime, 0).value_or(0));
}

QdEventFlags::TimePoint QdEventFlags::holdoff_end() const {
  return announced_once_ ? last_announcement_ + holdoff() : TimePoint::min();
}

void QdEventFlags::flag(unsigned subsystem, TimePoint now, std::vector<can::Frame>& out) {
  if (subsystem >= kSubsystems) return;
  const auto bit = static_cast<std::uint16_t>(1u << subsystem);
  if ((flags_ & bit) != 0) return;  // not re-armed yet: seeds/003 announces no further change
  flags_ = static_cast<std::uint16_t>(flags_ | bit);
  od_.set_unsigned(kEventResetRegister, 0, flags_);
  changed(now, out);
}

void QdEventFlags::changed(TimePoint now, std::vector<can::Frame>& out) {
  if (now >= holdoff_end()) {
    announce(now, out);
  } else {
    waiting_for_holdoff_ = true;
  }
}

void QdEventFlags::announce(TimePoint now, std::vector<can::Frame>& out) {
  waiting_for_holdoff_ = false;
  // CiA 301 sends an EMCY when the error code changes; changes undone within the hold-off are none.
  if (code() == announced_code_) return;
  announced_code_ = code();
  announced_once_ = true;
  last_announcement_ = now;
  if (flags_ != 0) {
    emcy_.raise(code(), kErrorRegisterBit, {}, now, out);
  } else {
    emcy_.clear_error(code(), kErrorRegisterBit, {}, now, out);
  }
}

void QdEventFlags::poll(TimePoint now, std::vector<can::Frame>& out) {
  if (waiting_for_holdoff_ && now >= holdoff_end()) announce(now, out);
}

QdEventFlags::TimePoint QdEventFlags::next_deadline() const {
  return waiting_for_holdoff_ ? holdoff_end() : TimePoint::max();
}

std::error_code QdEventFlags::check_write(const OdEntry& /*entry*/,
                                          std::span<const std::uint8_t> /*data*/) const {
  return {};
}

void QdEventFlags::on_written(const OdEntry& entry, TimePoint now, std::vector<can::Frame>& out) {
  if (entry.sub != 0) return;
  if (entry.index == kEventResetRegister) {
    const auto cleared = static_cast<std::uint16_t>(
        od_.get_unsigned(kEventResetRegister, 0).value_or(0) & kFlagMask);
    const auto remaining = static_cast<std::uint16_t>(flags_ & ~cleared);
    // The register reads back the flags, not the value written.
    od_.set_unsigned(kEventResetRegister, 0, remaining);
    if (remaining != flags_) {
      flags_ = remaining;
      changed(now, out);
    }
  } else if (entry.index == kHoldoffTime) {
    // A shorter hold-off may already have ended.
    poll(now, out);
  }
}

void QdEventFlags::reset() {
  flags_ = 0;
  announced_code_ = kCodeBase;
  announced_once_ = false;
  waiting_for_holdoff_ = false;
  od_.set_unsigned(kEventResetRegister, 0, 0);
}

}  // namespace canbridge::sim
