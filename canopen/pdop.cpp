#include "canopen/pdop.hpp"

#include <algorithm>

namespace canbridge::canopen::pdop {
namespace {

bool is_pdo_base(std::uint16_t base) {
  if ((base & 0x7Fu) != 0) return false;
  const auto code = static_cast<std::uint8_t>(base >> 7);
  return tpdo_number(code).has_value() || rpdo_number(code).has_value();
}

bool is_pdop_node(NodeId node) {
  return node >= 1 && node <= kMaxNode;
}

}  // namespace

std::vector<can::Frame> fragment(std::uint16_t pdo_base, NodeId node,
                                 std::span<const std::uint8_t> packet) {
  std::vector<can::Frame> frames;
  if (packet.empty() || packet.size() > kMaxPacketBytes || !is_pdo_base(pdo_base) ||
      !is_pdop_node(node)) {
    return frames;
  }
  const std::size_t count = (packet.size() + kFragmentBytes - 1) / kFragmentBytes;
  frames.reserve(count);
  const auto function_code = static_cast<std::uint8_t>(pdo_base >> 7);
  for (std::size_t k = 0; k < count; ++k) {
    const std::size_t offset = k * kFragmentBytes;
    const std::size_t length = std::min(kFragmentBytes, packet.size() - offset);
    const FragmentId id{function_code, k % 2 == 1, k + 1 < count, node};
    frames.push_back(can::Frame::from_span(encode(id), packet.subspan(offset, length)));
  }
  return frames;
}

can::Frame abort_frame(std::uint16_t pdo_base, NodeId node) {
  const FragmentId id{static_cast<std::uint8_t>(pdo_base >> 7), false, false, node};
  return can::Frame::standard(encode(id), {});
}

can::Frame encode_ack(NodeId node, const Ack& ack) {
  return can::Frame::standard(ack_cob_id(node),
                              {ack.rpdo, static_cast<std::uint8_t>(ack.status),
                               static_cast<std::uint8_t>(ack.received & 0xFFu),
                               static_cast<std::uint8_t>(ack.received >> 8), ack.credit});
}

std::optional<Ack> decode_ack(const can::Frame& frame) {
  if (frame.is_extended() || frame.is_remote() || frame.is_error()) return std::nullopt;
  if (frame.id <= kAckBase || frame.id > kAckBase + kMaxNode) return std::nullopt;
  if (frame.len != kAckLength) return std::nullopt;
  const auto& d = frame.data;
  if (d[0] < 1 || d[0] > 4) return std::nullopt;
  return Ack{d[0], static_cast<AckStatus>(d[1]),
             static_cast<std::uint16_t>(d[2] | (std::uint16_t{d[3]} << 8)), d[4]};
}

can::Frame ack_request(NodeId node) {
  can::Frame request = can::Frame::make(ack_cob_id(node), can::FrameFlags::remote, {});
  request.len = kAckLength;
  return request;
}

}  // namespace canbridge::canopen::pdop
