// Writes CAN frames as a pcap capture with the SocketCAN link type (LINKTYPE_CAN_SOCKETCAN, 227),
// which Wireshark and tshark open and dissect (docs/remote-access.md, "Capture").
#pragma once

#include <array>
#include <cstdint>
#include <ostream>

#include "can/frame.hpp"

namespace canbridge::can {

inline constexpr std::uint32_t kLinktypeCanSocketcan = 227;
// A pcap record's data: struct can_frame as Linux's packet socket captures it, 16 bytes.
inline constexpr std::size_t kSocketcanRecordBytes = 16;

// The 16-byte SocketCAN header + data of one frame: the CAN id with the EFF/RTR/ERR flags in
// network byte order (as libpcap's DLT_CAN_SOCKETCAN and Wireshark expect), length, 3 reserved
// bytes, 8 data bytes (zero past the length).
std::array<std::uint8_t, kSocketcanRecordBytes> socketcan_record(const Frame& frame);

class PcapWriter {
 public:
  // Writes the global header (microsecond timestamps, little-endian file) at once.
  explicit PcapWriter(std::ostream& out);
  // One record stamped with frame.timestamp (microseconds since the epoch, negative as 0).
  void write(const Frame& frame);

 private:
  std::ostream& out_;
};

}  // namespace canbridge::can
