// Options of the surface's remote access (bridge/remote_access.hpp): the 309-3 network numbers of
// the modules and how long the surface waits for a gateway's answer.
#pragma once

#include <chrono>
#include <cstdint>
#include <utility>
#include <vector>

namespace canbridge::bridge {

struct SurfaceRemoteOptions {
  // (module id, 309-3 network number); a module not listed has network module id + 1. Network
  // 0 is always the surface's one network (surface node ids).
  std::vector<std::pair<std::uint32_t, std::uint32_t>> networks;
  // Beyond the request's own SDO timeout: the backbone's round trips and the gateway's queue.
  std::chrono::milliseconds answer_slack{5000};
  // A flash request ends at the latest after this long.
  std::chrono::milliseconds flash_limit{std::chrono::minutes(10)};
  // After a request's deadline, how long the surface still waits for the gateway's answer
  // (RemoteRequestLedger::Options::resend_window): a result the gateway resends once a stalled
  // surface or a cut link is back is the answer, not a time-out.
  std::chrono::milliseconds resend_window{10000};
};

}  // namespace canbridge::bridge
