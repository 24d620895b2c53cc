#include "bridge/cob_id_translator.hpp"

namespace canbridge::bridge {

const char* to_string(DropReason reason) {
  switch (reason) {
    case DropReason::extended_id:
      return "extended-id";
    case DropReason::unknown_node:
      return "unknown-node";
    case DropReason::not_routable:
      return "not-routable";
    case DropReason::malformed_nmt:
      return "malformed-nmt";
    case DropReason::count_:
      break;
  }
  return "unknown";
}

std::optional<can::Frame> CobIdTranslator::to_surface(std::size_t module_index,
                                                      const can::Frame& frame) {
  if (frame.is_extended()) {
    count(DropReason::extended_id);
    return std::nullopt;
  }
  auto address = canopen::split_predefined(frame.id);
  if (!address) {
    // NMT, SYNC and TIME belong to the surface master; a module's own would collide.
    count(DropReason::not_routable);
    return std::nullopt;
  }
  const NodeId surface = map_.surface_of(module_index, address->node);
  if (surface == 0) {
    count(DropReason::unknown_node);
    return std::nullopt;
  }
  can::Frame out = frame;
  out.id = address->function_base + surface;
  return out;
}

}  // namespace canbridge::bridge
