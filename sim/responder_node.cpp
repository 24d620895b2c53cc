#include "sim/responder_node.hpp"

#include <algorithm>
#include <stdexcept>
#include <type_traits>
#include <variant>

#include "bridge/canopen/sdo_abort.hpp"

namespace canbridge::sim {

namespace sdo = canopen::sdo;
using canopen::NmtState;
using canopen::SdoAbort;

ResponderNode::ResponderNode(const ResponderConfig& config)
    : id_(config.node_id), auto_start_(config.auto_start) {
  if (id_ == 0 || id_ > canopen::kMaxNodeId) {
    throw std::invalid_argument("CANopen node id must be 1..127");
  }
  od_.add_unsigned(kDeviceType, 0, Access::constant, config.device_type, 4);
  od_.add_unsigned(kErrorRegister, 0, Access::ro, 0, 1);
  od_.add_unsigned(kHeartbeatTime, 0, Access::rw, config.heartbeat_ms, 2);
  od_.add_unsigned(kIdentity, 0, Access::constant, 4, 1);  // highest sub-index supported
  od_.add_unsigned(kIdentity, 1, Access::ro, config.identity.vendor_id, 4);
  od_.add_unsigned(kIdentity, 2, Access::ro, config.identity.product_code, 4);
  od_.add_unsigned(kIdentity, 3, Access::ro, config.identity.revision, 4);
  od_.add_unsigned(kIdentity, 4, Access::ro, config.identity.serial, 4);
}

std::chrono::milliseconds ResponderNode::heartbeat_period() const {
  return std::chrono::milliseconds(od_.get_unsigned(kHeartbeatTime, 0).value_or(0));
}

std::vector<can::Frame> ResponderNode::boot(TimePoint now) {
  std::vector<can::Frame> out;
  initialise(now, out);
  return out;
}

void ResponderNode::initialise(TimePoint now, std::vector<can::Frame>& out) {
  booted_ = true;
  // The boot-up message is the heartbeat frame with state 0 (CiA 301 7.2.8.3.2.1).
  out.push_back(error_control_frame(NmtState::boot_up));
  state_ = auto_start_ ? NmtState::operational : NmtState::pre_operational;
  schedule_heartbeat(now);
}

void ResponderNode::schedule_heartbeat(TimePoint now) {
  const auto period = heartbeat_period();
  next_heartbeat_ = period.count() == 0 ? TimePoint::max() : now + period;
}

can::Frame ResponderNode::error_control_frame(NmtState state) const {
  return can::Frame::standard(canopen::cob::heartbeat + id_, {static_cast<std::uint8_t>(state)});
}

std::vector<can::Frame> ResponderNode::on_tick(TimePoint now) {
  std::vector<can::Frame> out;
  if (!booted_ || now < next_heartbeat_) return out;
  out.push_back(error_control_frame(state_));
  const auto period = heartbeat_period();
  // Keep the cadence of the schedule rather than of our wake-ups; after a long stall send one
  // heartbeat, not a burst of the missed ones.
  next_heartbeat_ += period;
  if (period.count() == 0) {
    next_heartbeat_ = TimePoint::max();
  } else if (next_heartbeat_ <= now) {
    next_heartbeat_ = now + period;
  }
  return out;
}

std::vector<can::Frame> ResponderNode::on_frame(const can::Frame& frame, TimePoint now) {
  std::vector<can::Frame> out;
  // Remote frames would be node guarding, which this node does not implement (heartbeat only).
  if (!booted_ || frame.is_extended() || frame.is_remote() || frame.is_error()) return out;
  if (frame.id == canopen::cob::nmt) {
    handle_nmt(frame, now, out);
  } else if (frame.id == sdo::request_cob(id_)) {
    handle_sdo(frame, now, out);
  }
  return out;
}

void ResponderNode::handle_nmt(const can::Frame& frame, TimePoint now,
                               std::vector<can::Frame>& out) {
  // NMT node control is exactly 2 bytes: command, node id (0 = all nodes).
  if (frame.len != 2) return;
  const std::uint8_t target = frame.data[1];
  if (target != 0 && target != id_) return;
  switch (frame.data[0]) {
    case canopen::nmt::start:
      state_ = NmtState::operational;
      break;
    case canopen::nmt::stop:
      state_ = NmtState::stopped;
      break;
    case canopen::nmt::enter_pre_operational:
      state_ = NmtState::pre_operational;
      break;
    case canopen::nmt::reset_node:
      // Application reset: every object back to its power-on value.
      od_.restore_initial();
      initialise(now, out);
      break;
    case canopen::nmt::reset_communication:
      // Only the communication profile area (1000h..1FFFh) is reset.
      od_.restore_initial(0x1000, 0x1FFF);
      initialise(now, out);
      break;
    default:
      break;  // unknown command specifiers are ignored
  }
}

void ResponderNode::handle_sdo(const can::Frame& frame, TimePoint now,
                               std::vector<can::Frame>& out) {
  // CiA 301: SDO is not available in stopped, so the request goes unanswered.
  if (state_ == NmtState::stopped) return;
  const auto request = sdo::decode_request(frame);
  if (!request) return;
  auto abort = [&](sdo::Multiplexer mux, std::uint32_t code) {
    out.push_back(sdo::abort_response(id_, mux, code));
  };
  std::visit(
      [&](const auto& r) {
        using T = std::decay_t<decltype(r)>;
        if constexpr (std::is_same_v<T, sdo::UploadRequest>) {
          const auto read = od_.read(r.mux.index, r.mux.sub);
          if (read.error) {
            abort(r.mux, canopen::to_abort_code(read.error));
          } else if (read.value.size() > sdo::kMaxExpedited) {
            // Would need a segmented upload, which this server does not implement.
            abort(r.mux, static_cast<std::uint32_t>(SdoAbort::unsupported_access));
          } else {
            out.push_back(sdo::upload_response(id_, r.mux, read.value));
          }
        } else if constexpr (std::is_same_v<T, sdo::DownloadRequest>) {
          if (!r.expedited) {
            abort(r.mux, static_cast<std::uint32_t>(SdoAbort::invalid_command));
            return;
          }
          auto data = r.data.span();
          if (!r.size_indicated) {
            // Without a size the client sent 4 bytes; the object's own length says how many count.
            if (const OdEntry* entry = od_.find(r.mux.index, r.mux.sub)) {
              data = data.first(std::min(data.size(), entry->value.size()));
            }
          }
          if (const auto error = od_.write(r.mux.index, r.mux.sub, data)) {
            abort(r.mux, canopen::to_abort_code(error));
            return;
          }
          if (r.mux == sdo::Multiplexer{kHeartbeatTime, 0}) schedule_heartbeat(now);
          out.push_back(sdo::download_response(id_, r.mux));
        } else if constexpr (std::is_same_v<T, sdo::AbortTransfer>) {
          // Nothing to abort: expedited transfers hold no state between frames.
        } else {
          static_assert(std::is_same_v<T, sdo::UnsupportedRequest>);
          // Segmented and block transfers are not implemented; segment requests carry no object
          // address, so their abort names none.
          const bool addressed =
              r.command == sdo::ccs::block_upload || r.command == sdo::ccs::block_download;
          abort(addressed ? r.mux : sdo::Multiplexer{},
                static_cast<std::uint32_t>(SdoAbort::invalid_command));
        }
      },
      *request);
}

}  // namespace canbridge::sim
