// One CiA 305 LSS master service (the CiA 309-3 lss_* commands: switch global / selective,
// configure node-id, store, inquire identity or node-id) as a pure state machine: frames and an
// injected clock in, the request frames and one result out.
#pragma once

#include <chrono>
#include <cstdint>
#include <system_error>
#include <type_traits>
#include <vector>

#include "can/frame.hpp"
#include "canopen/cob_id.hpp"
#include "canopen/lss_protocol.hpp"

namespace canbridge::canopen {

// Why an LSS service failed, in the "canopen.lss" category: no answer in time, or the slave's
// error code in the configure / store answer.
enum class LssError {
  timeout = 1,                  // no answer within the timeout (309-3: "ERROR:103")
  node_id_out_of_range = 2,     // configure node-id answered 1
  not_supported = 3,            // store (or bit timing) answered 1
  storage_access = 4,           // store answered 2: the slave could not write its memory
  implementation_specific = 5,  // answered 0xFF; the slave's own code is in LssResult
  refused = 6,                  // any other (reserved) error code
};
const std::error_category& lss_category() noexcept;
std::error_code make_error_code(LssError error) noexcept;

// What to inquire (309-3 lss_inquire_addr 0..3, lss_get_node).
enum class LssInquiry : std::uint8_t { vendor = 0, product = 1, revision = 2, serial = 3, node_id };

struct LssResult {
  std::error_code error;           // empty on success
  std::uint32_t value = 0;         // the inquired value
  std::uint8_t answer_code = 0;    // configure / store: the answer's error code (byte 1)
  std::uint8_t specific_code = 0;  // ... and its implementation-specific code (byte 2)
  bool ok() const { return !error; }
};

// One service, from request to result. Switch global has no answer: it succeeds as soon as it is
// written (start()). The others wait up to `timeout` for their answer on 0x7E4; the first
// matching answer wins (LSS assumes one slave in configuration state). Answers with another
// command specifier are ignored: they belong to someone else's request.
class LssMaster {
 public:
  using Clock = std::chrono::steady_clock;
  using TimePoint = Clock::time_point;

  static LssMaster switch_global(bool configuration, std::chrono::milliseconds timeout);
  // Four requests; the addressed slave answers the last one (and enters configuration state).
  static LssMaster switch_selective(const lss::Address& address, std::chrono::milliseconds timeout);
  // 1..127, or 0xFF (unconfigured); throws std::invalid_argument otherwise (309-3's syntax
  // check belongs to the caller, the slave's range check to the slave).
  static LssMaster configure_node_id(std::uint8_t node_id, std::chrono::milliseconds timeout);
  static LssMaster store_configuration(std::chrono::milliseconds timeout);
  static LssMaster inquire(LssInquiry what, std::chrono::milliseconds timeout);

  void start(TimePoint now, std::vector<can::Frame>& out);
  // Any frame read on the bus; only LSS answers (0x7E4) act.
  void on_frame(const can::Frame& frame, TimePoint now);
  // Ends the service with LssError::timeout once now >= deadline().
  void on_timeout(TimePoint now);

  TimePoint deadline() const { return finished_ ? TimePoint::max() : deadline_; }
  bool finished() const { return finished_; }
  // Valid once finished().
  const LssResult& result() const { return result_; }

 private:
  LssMaster(std::vector<can::Frame> requests, std::uint8_t answer,
            std::chrono::milliseconds timeout);
  void finish(LssResult result);

  std::vector<can::Frame> requests_;
  std::uint8_t answer_ = 0;  // the command specifier of the awaited answer; 0: none awaited
  std::chrono::milliseconds timeout_{};
  TimePoint deadline_ = TimePoint::max();
  bool finished_ = false;
  LssResult result_{};
};

}  // namespace canbridge::canopen

template <>
struct std::is_error_code_enum<canbridge::canopen::LssError> : std::true_type {};
