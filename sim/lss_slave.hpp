// A minimal CiA 305 LSS slave for the simulated cia301 node: switch global / selective,
// configure node-id, store, inquire identity and node-id, so that an LSS master can be tested
// against something that behaves like a device. A pure core: frames in, answers out.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/lss_protocol.hpp"

namespace canbridge::sim {

struct LssSlaveOptions {
  canopen::lss::Address address;  // the node's 1018h values
  canopen::NodeId active_node_id = 1;
  // False models a slave without non-volatile memory: store answers "not supported".
  bool store_supported = true;
};

class LssSlave {
 public:
  explicit LssSlave(LssSlaveOptions options);

  // A frame on 0x7E5 (others are ignored); appends the answer, if the command has one.
  void on_frame(const can::Frame& frame, std::vector<can::Frame>& out);

  bool in_configuration() const { return configuration_; }
  // The node-id configured over LSS and not yet active (CiA 305: it becomes active at the next
  // NMT reset communication); nullopt when none was configured or it equals the active one.
  std::optional<canopen::NodeId> pending_node_id() const;
  // The node now uses `id` (after a reset communication applied the pending one).
  void set_active_node_id(canopen::NodeId id) { options_.active_node_id = id; }
  canopen::NodeId active_node_id() const { return options_.active_node_id; }
  // The node-id last stored with "store configuration"; nullopt before any store.
  std::optional<std::uint8_t> stored_node_id() const { return stored_; }

 private:
  void answer(std::uint8_t command, std::uint32_t value, std::vector<can::Frame>& out) const;

  LssSlaveOptions options_;
  bool configuration_ = false;
  // Switch selective: the next of vendor/product/revision/serial expected (0..3), or -1 after
  // a mismatch (the rest of that sequence is ignored).
  int selective_next_ = 0;
  std::uint8_t pending_ = canopen::lss::unconfigured_node_id;  // 0xFF: nothing configured
  std::optional<std::uint8_t> stored_;
};

}  // namespace canbridge::sim
