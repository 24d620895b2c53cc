// Pure encoding and decoding of CiA 301 SDO frames for expedited transfers and aborts: no state,
// no I/O, so clients, servers and the protocol checker share one definition of the wire format.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <system_error>
#include <variant>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::canopen::sdo {

// Every SDO frame is 8 bytes (CiA 301); shorter frames are not SDO and decode to nullopt.
inline constexpr std::uint8_t kFrameLength = 8;
inline constexpr std::size_t kMaxExpedited = 4;
inline constexpr std::size_t kSegmentBytes = 7;  // data bytes of a segment, after byte 0

// Byte 0 bits outside the command specifier (CiA 301 7.2.4.3), shared by every SDO state machine.
// Initiate (download request, upload response): n bits 3..2, e bit 1, s bit 0.
inline constexpr std::uint8_t kExpedited = 0x02;
inline constexpr std::uint8_t kSizeIndicated = 0x01;
// Segments: t bit 4, n bits 3..1, c bit 0.
inline constexpr std::uint8_t kToggle = 0x10;
inline constexpr std::uint8_t kLastSegment = 0x01;
// Block commands: cc/sc bit 2, s bit 1. Block segments: c bit 7, seqno bits 6..0.
inline constexpr std::uint8_t kCrcSupported = 0x04;
inline constexpr std::uint8_t kBlockSizeIndicated = 0x02;
inline constexpr std::uint8_t kBlockLastSegment = 0x80;
inline constexpr std::uint8_t kSeqnoMask = 0x7F;

// Command specifiers: bits 7..5 of byte 0. Client and server numbering differ (CiA 301 7.2.4.3).
namespace ccs {
inline constexpr std::uint8_t download_segment = 0;
inline constexpr std::uint8_t initiate_download = 1;
inline constexpr std::uint8_t initiate_upload = 2;
inline constexpr std::uint8_t upload_segment = 3;
inline constexpr std::uint8_t abort = 4;
inline constexpr std::uint8_t block_upload = 5;
inline constexpr std::uint8_t block_download = 6;
}  // namespace ccs
namespace scs {
inline constexpr std::uint8_t upload_segment = 0;
inline constexpr std::uint8_t download_segment = 1;
inline constexpr std::uint8_t initiate_upload = 2;
inline constexpr std::uint8_t initiate_download = 3;
inline constexpr std::uint8_t abort = 4;
inline constexpr std::uint8_t block_download = 5;
inline constexpr std::uint8_t block_upload = 6;
}  // namespace scs
// Sub-commands in the low bits of byte 0 of the block services: bits 1..0 for ccs 5 and scs 5,
// bit 0 for ccs 6 and scs 6.
namespace block_upload_cs {  // client, ccs 5
inline constexpr std::uint8_t initiate = 0;
inline constexpr std::uint8_t end = 1;
inline constexpr std::uint8_t ack = 2;
inline constexpr std::uint8_t start = 3;
}  // namespace block_upload_cs
namespace block_download_cs {  // client, ccs 6
inline constexpr std::uint8_t initiate = 0;
inline constexpr std::uint8_t end = 1;
}  // namespace block_download_cs
namespace block_download_ss {  // server, scs 5
inline constexpr std::uint8_t initiate = 0;
inline constexpr std::uint8_t end = 1;
inline constexpr std::uint8_t ack = 2;
}  // namespace block_download_ss
namespace block_upload_ss {  // server, scs 6
inline constexpr std::uint8_t initiate = 0;
inline constexpr std::uint8_t end = 1;
}  // namespace block_upload_ss

constexpr std::uint32_t request_cob(NodeId node) {
  return cob::sdo_rx + node;
}
constexpr std::uint32_t response_cob(NodeId node) {
  return cob::sdo_tx + node;
}

// Object dictionary address carried in bytes 1..3 (index little-endian, then sub-index).
struct Multiplexer {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  friend bool operator==(const Multiplexer&, const Multiplexer&) = default;
};

// The data bytes of an expedited transfer. When the sender did not indicate the size (s = 0),
// all 4 bytes are returned and the receiver decides how many it uses.
struct ExpeditedData {
  std::array<std::uint8_t, kMaxExpedited> bytes{};
  std::uint8_t size = 0;
  std::span<const std::uint8_t> span() const { return {bytes.data(), size}; }
};

// Client -> server.
struct UploadRequest {
  Multiplexer mux;
};
struct DownloadRequest {
  Multiplexer mux;
  bool expedited = false;
  bool size_indicated = false;
  ExpeditedData data;      // expedited only
  std::uint32_t size = 0;  // segmented with size indicated: total bytes to follow
};
// A request this codec does not model: segment, block and reserved command specifiers. `mux` is
// bytes 1..3 as received; it is an object address only for initiate commands.
struct UnsupportedRequest {
  std::uint8_t command = 0;
  Multiplexer mux;
};

// Server -> client.
struct UploadResponse {
  Multiplexer mux;
  bool expedited = false;
  bool size_indicated = false;
  ExpeditedData data;      // expedited only
  std::uint32_t size = 0;  // segmented with size indicated: total bytes to follow
};
struct DownloadResponse {
  Multiplexer mux;
};
struct UnsupportedResponse {
  std::uint8_t command = 0;
  Multiplexer mux;
};

// Either direction.
struct AbortTransfer {
  Multiplexer mux;
  std::uint32_t code = 0;
  std::error_code error() const { return abort_error(code); }
};

// Layout every SDO service shares: an 8-byte standard data frame, the multiplexer in bytes 1..3,
// a 32-bit value (size, abort code, data) in bytes 4..7. For the block and segment services the
// server and client build on top of this codec.
bool is_sdo_frame(const can::Frame& frame);
Multiplexer read_multiplexer(const can::Frame& frame);
void write_multiplexer(can::Frame& frame, Multiplexer mux);
std::uint32_t read_u32(const can::Frame& frame, std::size_t at);
void write_u32(can::Frame& frame, std::size_t at, std::uint32_t value);

using Request = std::variant<UploadRequest, DownloadRequest, AbortTransfer, UnsupportedRequest>;
using Response = std::variant<UploadResponse, DownloadResponse, AbortTransfer, UnsupportedResponse>;

// nullopt unless the frame is an 8-byte standard data frame. The COB-ID is not checked: the
// caller knows which channel it listens on.
std::optional<Request> decode_request(const can::Frame& frame);
std::optional<Response> decode_response(const can::Frame& frame);

// Builders. Expedited `data` must hold 1..4 bytes (std::invalid_argument otherwise): more needs a
// segmented transfer, which callers must choose explicitly.
can::Frame upload_request(NodeId node, Multiplexer mux);
can::Frame download_request(NodeId node, Multiplexer mux, std::span<const std::uint8_t> data);
can::Frame upload_response(NodeId node, Multiplexer mux, std::span<const std::uint8_t> data);
// Initiates a segmented upload of `size` bytes; used to exercise clients that do not support it.
can::Frame segmented_upload_response(NodeId node, Multiplexer mux, std::uint32_t size);
can::Frame download_response(NodeId node, Multiplexer mux);
// An abort sent by the client (COB 0x600 + node) or by the server (COB 0x580 + node).
can::Frame abort_request(NodeId node, Multiplexer mux, std::uint32_t code);
can::Frame abort_response(NodeId node, Multiplexer mux, std::uint32_t code);
inline can::Frame abort_request(NodeId node, Multiplexer mux, SdoAbort code) {
  return abort_request(node, mux, static_cast<std::uint32_t>(code));
}
inline can::Frame abort_response(NodeId node, Multiplexer mux, SdoAbort code) {
  return abort_response(node, mux, static_cast<std::uint32_t>(code));
}

}  // namespace canbridge::canopen::sdo
