#include "can/pcap_writer.hpp"

#include <chrono>

namespace canbridge::can {

namespace {

// Linux can.h flag bits of can_id.
constexpr std::uint32_t kEffFlag = 0x80000000U;
constexpr std::uint32_t kRtrFlag = 0x40000000U;
constexpr std::uint32_t kErrFlag = 0x20000000U;

void put_le32(std::ostream& out, std::uint32_t v) {
  const char b[4] = {static_cast<char>(v), static_cast<char>(v >> 8), static_cast<char>(v >> 16),
                     static_cast<char>(v >> 24)};
  out.write(b, 4);
}

void put_le16(std::ostream& out, std::uint16_t v) {
  const char b[2] = {static_cast<char>(v), static_cast<char>(v >> 8)};
  out.write(b, 2);
}

}  // namespace

std::array<std::uint8_t, kSocketcanRecordBytes> socketcan_record(const Frame& frame) {
  std::uint32_t id = frame.id & (frame.is_extended() ? kMaxExtendedId : kMaxStandardId);
  if (frame.is_extended()) id |= kEffFlag;
  if (frame.is_remote()) id |= kRtrFlag;
  if (frame.is_error()) id = (frame.id & kMaxExtendedId) | kErrFlag;
  std::array<std::uint8_t, kSocketcanRecordBytes> r{};
  r[0] = static_cast<std::uint8_t>(id >> 24);
  r[1] = static_cast<std::uint8_t>(id >> 16);
  r[2] = static_cast<std::uint8_t>(id >> 8);
  r[3] = static_cast<std::uint8_t>(id);
  r[4] = static_cast<std::uint8_t>(std::min<std::size_t>(frame.len, kMaxPayload));
  const auto payload = frame.payload();
  std::copy(payload.begin(), payload.end(), r.begin() + 8);
  return r;
}

PcapWriter::PcapWriter(std::ostream& out) : out_(out) {
  put_le32(out_, 0xA1B2C3D4U);  // magic: microsecond timestamps
  put_le16(out_, 2);            // version 2.4
  put_le16(out_, 4);
  put_le32(out_, 0);      // thiszone
  put_le32(out_, 0);      // sigfigs
  put_le32(out_, 65535);  // snaplen
  put_le32(out_, kLinktypeCanSocketcan);
}

void PcapWriter::write(const Frame& frame) {
  const auto us = std::chrono::duration_cast<std::chrono::microseconds>(frame.timestamp).count();
  const auto t = static_cast<std::uint64_t>(us < 0 ? 0 : us);
  put_le32(out_, static_cast<std::uint32_t>(t / 1'000'000));
  put_le32(out_, static_cast<std::uint32_t>(t % 1'000'000));
  put_le32(out_, kSocketcanRecordBytes);
  put_le32(out_, kSocketcanRecordBytes);
  const auto record = socketcan_record(frame);
  out_.write(reinterpret_cast<const char*>(record.data()), record.size());
}

}  // namespace canbridge::can
