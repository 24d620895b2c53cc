// What the surface's operator reads for each node event: the node by gateway, module and both
// ids, a loss and an unconfirmed rename as warnings, an unknown kind only at debug level.
#include "bridge/node_event_text.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

using Level = NodeEventLine::Level;

v1::NodeEvent event(v1::NodeEvent::Kind kind) {
  v1::NodeEvent e;
  e.set_kind(kind);
  e.set_module_id(2);
  e.set_local_node(5);
  e.set_surface_node(69);
  e.set_nmt_state(0x05);
  return e;
}

TEST(NodeEventText, ALossIsAWarningNamingTheNodeByBothIds) {
  const NodeEventLine line = node_event_line("tool-1", event(v1::NodeEvent::LOST));
  EXPECT_EQ(line.level, Level::warning);
  EXPECT_EQ(line.text, "gateway 'tool-1' module 2 node 5 (surface 69) lost: its heartbeat stopped");
}

TEST(NodeEventText, EachKindSaysWhatHappened) {
  v1::NodeEvent renamed = event(v1::NodeEvent::RENAMED);
  renamed.set_previous_local_node(4);
  renamed.set_previous_surface_node(68);
  EXPECT_EQ(node_event_line("g", renamed).text,
            "gateway 'g' module 2 node 5 (surface 69) renamed from node 4 (surface 68)");
  EXPECT_EQ(node_event_line("g", event(v1::NodeEvent::STATE_CHANGED)).text,
            "gateway 'g' module 2 node 5 (surface 69) is operational");
  EXPECT_EQ(node_event_line("g", event(v1::NodeEvent::LOADER_BOOTED)).level, Level::info);
  v1::NodeEvent census = event(v1::NodeEvent::DISCOVERED);  // the gateway's loader census
  census.set_in_loader(true);
  EXPECT_EQ(node_event_line("g", census).text,
            "gateway 'g' module 2 node 5 (surface 69) found waiting in its loader");
  EXPECT_EQ(node_event_line("g", event(v1::NodeEvent::RENAME_UNCONFIRMED)).level, Level::warning);
  v1::NodeEvent answering = event(v1::NodeEvent::DISCOVERED);  // heard only by its SDO answer
  answering.set_nmt_state(0xFF);
  EXPECT_EQ(node_event_line("g", answering).text,
            "gateway 'g' module 2 node 5 (surface 69) found answering (no heartbeat; state "
            "unknown until it sends one)");
}

TEST(NodeEventText, AKindThisVersionDoesNotKnowIsOnlyADebugLine) {
  const NodeEventLine line = node_event_line("g", event(static_cast<v1::NodeEvent::Kind>(99)));
  EXPECT_EQ(line.level, Level::debug);
  EXPECT_NE(line.text.find("unknown kind 99"), std::string::npos);
}

}  // namespace
}  // namespace canbridge::bridge
