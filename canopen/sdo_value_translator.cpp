#include "canopen/sdo_value_translator.hpp"

namespace canbridge::canopen::sdo {

namespace {

constexpr std::uint32_t kFrame29Bit = 1u << 29;  // CiA 301 COB-ID entry: 29-bit identifier
constexpr std::uint32_t kStandardIdMask = 0x7FF;

// Rewrites the expedited value of `frame` (bytes 4..7) in place; the command byte tells how many
// bytes are valid (n in bits 2-3 when s = 1).
ValueRewrite rewrite_expedited(can::Frame& frame, const IdMapping& map) {
  const Multiplexer mux = read_multiplexer(frame);
  const ValueKind kind = value_kind(mux);
  if (kind == ValueKind::none) return ValueRewrite::unchanged;
  const std::uint8_t command = frame.data[0];
  const bool size_indicated = (command & 0x01) != 0;
  const std::size_t size = size_indicated ? 4 - ((command >> 2) & 0x03) : 4;
  const std::size_t expected = kind == ValueKind::node_id ? 1 : 4;
  if (size_indicated && size != expected) return ValueRewrite::unchanged;  // the node will abort
  std::uint32_t value = read_u32(frame, 4);
  if (kind == ValueKind::node_id) value &= 0xFF;
  const TranslatedValue t = translate_value(kind, value, map);
  if (!t.mapped) return ValueRewrite::no_counterpart;
  if (t.value == value) return ValueRewrite::unchanged;
  if (kind == ValueKind::node_id) {
    frame.data[4] = static_cast<std::uint8_t>(t.value);
  } else {
    write_u32(frame, 4, t.value);
  }
  return ValueRewrite::rewritten;
}

}  // namespace

ValueKind value_kind(Multiplexer mux) {
  const std::uint16_t i = mux.index;
  if (i >= 0x1200 && i <= 0x12FF) {
    // Server (1200h-127Fh) and client (1280h-12FFh) parameters alike: sub 3 names the peer, the
    // client of a server channel or the server of a client channel.
    if (mux.sub == 1 || mux.sub == 2) return ValueKind::cob_id;
    return mux.sub == 3 ? ValueKind::node_id : ValueKind::none;
  }
  if ((i >= 0x1400 && i <= 0x15FF) || (i >= 0x1800 && i <= 0x19FF)) {
    return mux.sub == 1 ? ValueKind::cob_id : ValueKind::none;
  }
  if (i == 0x1014) return mux.sub == 0 ? ValueKind::cob_id : ValueKind::none;
  // Emergency consumer: sub n holds the COB-ID of the EMCY the node consumes from node n.
  if (i == 0x1028) return mux.sub >= 1 && mux.sub <= 127 ? ValueKind::cob_id : ValueKind::none;
  if (i == 0x1016)
    return mux.sub >= 1 && mux.sub <= 127 ? ValueKind::node_in_16_23 : ValueKind::none;
  return ValueKind::none;
}

TranslatedValue translate_value(ValueKind kind, std::uint32_t value, const IdMapping& map) {
  switch (kind) {
    case ValueKind::none:
      return {value, true};
    case ValueKind::cob_id: {
      if (value & kFrame29Bit) return {value, true};
      const auto id = map.cob_id ? map.cob_id(value & kStandardIdMask) : std::nullopt;
      if (!id) return {value, false};
      return {(value & ~kStandardIdMask) | (*id & kStandardIdMask), true};
    }
    case ValueKind::node_in_16_23: {
      const auto node = static_cast<NodeId>((value >> 16) & 0xFF);
      if (node == 0) return {value, true};
      const auto mapped = map.node_id ? map.node_id(node) : std::nullopt;
      if (!mapped) return {value, false};
      return {(value & 0xFF00FFFFu) | (std::uint32_t{*mapped} << 16), true};
    }
    case ValueKind::node_id: {
      const auto node = static_cast<NodeId>(value & 0xFF);
      if (node == 0) return {value, true};
      const auto mapped = map.node_id ? map.node_id(node) : std::nullopt;
      if (!mapped) return {value, false};
      return {*mapped, true};
    }
  }
  return {value, true};
}

ValueRewrite rewrite_request(can::Frame& request, const IdMapping& to_local) {
  if (!is_sdo_frame(request)) return ValueRewrite::unchanged;
  const std::uint8_t command = request.data[0];
  const bool initiate_download = (command >> 5) == ccs::initiate_download;
  const bool expedited = (command & 0x02) != 0;
  if (!initiate_download || !expedited) return ValueRewrite::unchanged;
  return rewrite_expedited(request, to_local);
}

ValueRewrite rewrite_response(can::Frame& response, const IdMapping& to_surface) {
  if (!is_sdo_frame(response)) return ValueRewrite::unchanged;
  const std::uint8_t command = response.data[0];
  const bool initiate_upload = (command >> 5) == scs::initiate_upload;
  const bool expedited = (command & 0x02) != 0;
  if (!initiate_upload || !expedited) return ValueRewrite::unchanged;
  return rewrite_expedited(response, to_surface);
}

}  // namespace canbridge::canopen::sdo
