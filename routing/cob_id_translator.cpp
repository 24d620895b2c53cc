#include "routing/cob_id_translator.hpp"

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
    case DropReason::rename_refused:
      return "rename-refused";
    case DropReason::lss_unrouted:
      return "lss-unrouted";
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
  if (frame.id == canopen::cob::lss_slave) {
    if (module_index != lss_module_) {
      count(DropReason::lss_unrouted);
      return std::nullopt;
    }
    can::Frame out = frame;
    // The inquired node id, as the master must address the node: its surface id. An id the
    // module does not map goes as it is (the master cannot reach that node anyway).
    if (frame.len >= 2 && frame.data[0] == kLssInquireNodeId) {
      if (const NodeId surface = map_.surface_of(module_index, frame.data[1])) {
        out.data[1] = surface;
      }
    }
    return out;
  }
  const std::uint16_t surface = map_.surface_cob_of(module_index, frame.id);
  if (surface == 0) {
    // NMT, SYNC and TIME belong to the surface master; a module's own would collide. A
    // node-addressed COB-ID (under the module's profile) of an unmapped node is counted apart.
    const IdProfile profile = map_.modules()[module_index].profile;
    count(is_node_addressed(profile, frame.id) ? DropReason::unknown_node
                                               : DropReason::not_routable);
    return std::nullopt;
  }
  can::Frame out = frame;
  out.id = surface;
  return out;
}

}  // namespace canbridge::bridge
