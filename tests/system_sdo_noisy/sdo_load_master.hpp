// A surface master for system tests that keeps SDO requests flowing at a steady rate to several
// nodes, as a master polling a bus does, and records how each request ended: answered,
// aborted, or not answered within a bound. One expedited request per node at a time (the SDO
// protocol allows no more); each request carries its sequence number (the value of a download,
// the reserved bytes of an upload), so the module bus shows which request reached a node.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::test {

struct SdoLoadOptions {
  std::vector<std::uint8_t> nodes;       // the servers' node ids on the master's bus
  std::chrono::milliseconds period{10};  // one request per period (fewer while every node is busy)
  std::chrono::milliseconds answer_bound{6000};  // no answer by then: the request vanished
  std::uint16_t index = 0x2000;                  // an rw UNSIGNED32 on every node
  std::uint8_t sub = 0;
  // Each request to an object of its own (numbered_object(seq)), so that every answer, an abort
  // included, names the request it answers; the nodes answer these with their own abort
  // (object does not exist), which shows the request reached them.
  bool numbered_objects = false;
};

// The object (index, sub-index) of request `seq` when SdoLoadOptions::numbered_objects is set:
// 3000h + seq / 256, sub-index seq % 256.
struct SdoObject {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
};
SdoObject numbered_object(std::uint32_t seq);

struct SdoRequestRecord {
  enum class End { pending, response, abort, none };
  std::uint32_t seq = 0;
  std::uint8_t node = 0;
  bool download = false;  // else an upload
  std::chrono::steady_clock::time_point sent;
  End end = End::pending;
  std::uint32_t abort_code = 0;
  std::chrono::steady_clock::time_point answered;  // when the response or abort arrived
};

// The sequence number a request frame carries, if `frame` is an expedited download or an upload
// initiate of this master's object (seen on any bus, whatever its COB-ID).
std::optional<std::uint32_t> load_request_seq(const can::Frame& frame, const SdoLoadOptions& o);

class SdoLoadMaster {
 public:
  SdoLoadMaster(std::string interface, SdoLoadOptions options)
      : interface_(std::move(interface)), options_(std::move(options)) {}

  // Sends requests until `send_until`, alternating downloads and uploads and going round the
  // nodes, then waits for the last answers; returns when every request has ended.
  void run(std::chrono::steady_clock::time_point send_until);

  const std::vector<SdoRequestRecord>& requests() const { return requests_; }
  // SDO frames from a node with no request outstanding, or naming another object.
  std::size_t stray_answers() const { return stray_answers_; }
  // Periods in which every node still had its request outstanding (the rate fell behind).
  std::size_t all_busy() const { return all_busy_; }
  // numbered_objects: answers naming a request of this master that had ended already (its
  // answer came, or the master gave up on it): an answer the master cannot place.
  std::size_t late_answers() const { return late_answers_; }
  // The first few of them: "#seq (code, after End, ms after it ended)", for failure messages.
  const std::string& late_answer_list() const { return late_answer_list_; }

 private:
  can::Frame request_frame(std::uint32_t seq, bool download, std::uint8_t node) const;
  SdoObject object_of(std::uint32_t seq) const;
  // Ends the outstanding request of the node that sent `frame`, or counts a stray.
  void on_answer(const can::Frame& frame, std::chrono::steady_clock::time_point now,
                 std::vector<std::optional<std::size_t>>& outstanding);

  std::string interface_;
  SdoLoadOptions options_;
  std::vector<SdoRequestRecord> requests_;
  std::size_t stray_answers_ = 0;
  std::size_t all_busy_ = 0;
  std::size_t late_answers_ = 0;
  std::string late_answer_list_;
};

}  // namespace canbridge::test
