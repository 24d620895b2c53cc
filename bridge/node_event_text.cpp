#include "bridge/node_event_text.hpp"

#include <fmt/format.h>

#include "canopen/cob_id.hpp"

namespace canbridge::bridge {

NodeEventLine node_event_line(std::string_view gateway, const v1::NodeEvent& e) {
  using Level = NodeEventLine::Level;
  const std::string node = fmt::format("gateway '{}' module {} node {} (surface {})", gateway,
                                       e.module_id(), e.local_node(), e.surface_node());
  switch (e.kind()) {
    case v1::NodeEvent::BOOTED:
      return {Level::info,
              fmt::format("{} booted (boot-up {} seen by the gateway)", node, e.boot_count())};
    case v1::NodeEvent::STATE_CHANGED:
      return {Level::info, fmt::format("{} is {}", node, canopen::nmt_state_name(e.nmt_state()))};
    case v1::NodeEvent::LOST:
      return {Level::warning, fmt::format("{} lost: its heartbeat stopped", node)};
    case v1::NodeEvent::RECOVERED:
      return {Level::info,
              fmt::format("{} is back ({})", node, canopen::nmt_state_name(e.nmt_state()))};
    case v1::NodeEvent::RENAMED:
      return {Level::info, fmt::format("{} renamed from node {} (surface {})", node,
                                       e.previous_local_node(), e.previous_surface_node())};
    case v1::NodeEvent::RENAME_UNCONFIRMED:
      return {Level::warning,
              fmt::format("{}: set-node-id sent, no boot-up on the new id in time", node)};
    case v1::NodeEvent::DISCOVERED:
      if (e.in_loader()) return {Level::info, fmt::format("{} found waiting in its loader", node)};
      if (e.nmt_state() == static_cast<std::uint32_t>(canopen::NmtState::unknown)) {
        return {Level::info,
                fmt::format("{} found answering (no heartbeat; state unknown until it sends one)",
                            node)};
      }
      return {Level::info,
              fmt::format("{} found ({})", node, canopen::nmt_state_name(e.nmt_state()))};
    case v1::NodeEvent::LOADER_BOOTED:
      return {Level::info, fmt::format("{} is in its loader", node)};
    default:
      return {Level::debug,
              fmt::format("{}: node event of unknown kind {}", node, static_cast<int>(e.kind()))};
  }
}

}  // namespace canbridge::bridge
