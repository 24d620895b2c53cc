// The backbone settings a role hands to its sessions and outboxes (app/tuning_from_options.hpp
// builds them from the role's config).
#pragma once

#include "backbone/session.hpp"
#include "bridge/frame_outbox.hpp"

namespace canbridge::bridge {

struct BackboneTuning {
  backbone::SessionOptions session;
  FrameOutbox::Options outbox;
};

}  // namespace canbridge::bridge
