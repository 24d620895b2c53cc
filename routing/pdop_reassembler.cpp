#include "routing/pdop_reassembler.hpp"

#include <algorithm>
#include <bit>
#include <stdexcept>

namespace canbridge::bridge {

namespace pdop = canopen::pdop;

namespace {

constexpr std::size_t kFragmentBytes = pdop::kFragmentBytes;
constexpr std::uint32_t kPdopToggleBit = 0x40;     // docs/pdop.md section 1
constexpr std::uint32_t kPdopContinuedBit = 0x20;  // docs/pdop.md section 1
constexpr std::uint32_t kPdopNodeBits = 0x1F;

std::size_t stream_index(PdopReassembler::NodeId node, unsigned tpdo) {
  return (std::size_t{node} - 1) * PdopReassembler::kTpdoCount + (tpdo - 1);
}
PdopReassembler::NodeId node_of(std::size_t index) {
  return static_cast<PdopReassembler::NodeId>(index / PdopReassembler::kTpdoCount + 1);
}
unsigned tpdo_of(std::size_t index) {
  return static_cast<unsigned>(index % PdopReassembler::kTpdoCount + 1);
}

}  // namespace

std::optional<std::string> PdopReassemblerOptions::validate() const {
  if (max_packet_bytes < 1 || max_packet_bytes > pdop::kMaxPacketBytes) {
    return "max_packet_bytes: " + std::to_string(max_packet_bytes) + " is outside 1.." +
           std::to_string(pdop::kMaxPacketBytes);
  }
  if (fragment_timeout < kMinFragmentTimeout || fragment_timeout > kMaxFragmentTimeout) {
    return "fragment_timeout: " + std::to_string(fragment_timeout.count()) +
           " ms is outside 1..10000 ms";
  }
  return std::nullopt;
}

std::uint64_t PdopReassembler::Counters::discards_total() const {
  std::uint64_t total = 0;
  for (std::uint64_t n : discards) total += n;
  return total;
}

PdopReassembler::PdopReassembler() : PdopReassembler(PdopReassemblerOptions{}) {}

PdopReassembler::PdopReassembler(const PdopReassemblerOptions& options)
    : options_(options), timeout_(options.fragment_timeout) {
  if (auto problem = options.validate())
    throw std::invalid_argument("PDOP reassembler: " + *problem);
}

bool PdopReassembler::on_frame(const can::Frame& frame, TimePoint now, Sink& sink) {
  // Standard data frames only: no extended, remote or error flag.
  if (!frame.is_standard_data() || frame.len > can::kMaxPayload) return false;
  const std::uint32_t id = frame.id;
  const std::uint32_t function_code = id >> 7;  // 0..15 for an 11-bit id
  // TPDO1..4: function codes 3, 5, 7, 9.
  if (function_code < 3 || function_code > 9 || (function_code & 1u) == 0) return false;
  const auto node = static_cast<NodeId>(id & kPdopNodeBits);
  if (node == 0) return false;
  const unsigned tpdo = (function_code - 1) / 2;
  ++counters_.frames;
  on_fragment(stream_index(node, tpdo), (id & kPdopToggleBit) != 0, (id & kPdopContinuedBit) != 0,
              frame.payload(), now, sink);
  return true;
}

void PdopReassembler::on_fragment(std::size_t index, bool toggle, bool continued,
                                  std::span<const std::uint8_t> data, TimePoint now, Sink& sink) {
  Stream& s = streams_[index];
  if (s.state == State::assembling && now >= s.deadline) {
    fail(index, Reason::timeout, now, sink, false, false);
  }
  switch (s.state) {
    case State::resynchronising:
      ++counters_.dropped_frames;
      if (!continued) s.state = State::idle;
      return;
    case State::idle:
    case State::assembling:
      break;
  }
  // Section 2: not a fragment; refused whatever the toggle.
  if (data.empty() && !continued) return fail(index, Reason::empty_frame, now, sink, true, false);
  const bool expected = s.state == State::assembling && s.expected_toggle;
  if (toggle != expected) {
    const Reason reason =
        repeats_previous(s, toggle, continued, data) ? Reason::duplicate : Reason::missing_fragment;
    return fail(index, reason, now, sink, true, continued);
  }
  accept(index, toggle, continued, data, now, sink);
}

void PdopReassembler::accept(std::size_t index, bool toggle, bool continued,
                             std::span<const std::uint8_t> data, TimePoint now, Sink& sink) {
  Stream& s = streams_[index];
  // Checked before the previous fragment is forgotten below.
  const bool probable_repeat =
      s.state == State::idle && !continued && !toggle && s.previous_packet_fragments > 1 &&
      repeats_previous(s, toggle, continued, data) && now - s.last <= kRepeatWindow;
  if (s.state == State::idle) {
    s.bytes.clear();
    s.fragments = 0;
    s.first = now;
    s.has_previous = false;
  }
  if (continued && data.size() < kFragmentBytes) {
    return fail(index, Reason::short_fragment, now, sink, true, continued);
  }
  if (data.size() > options_.max_packet_bytes - s.bytes.size()) {
    return fail(index, Reason::oversize, now, sink, true, continued);
  }
  if (s.state == State::idle && !continued) {
    // A one-frame packet (a plain TPDO): delivered from the frame, the buffer stays untouched.
    remember(s, toggle, continued, data);
    s.last = now;
    s.previous_packet_fragments = 1;
    deliver(index, data, 1, now, now, sink, probable_repeat);
    return;
  }
  const std::size_t size = s.bytes.size() + data.size();
  if (size > s.bytes.capacity()) {
    // Grow geometrically, but never past max_packet_bytes: the memory bound of the header.
    s.bytes.reserve(std::min(options_.max_packet_bytes,
                             std::max({size, 2 * s.bytes.capacity(), std::size_t{64}})));
  }
  s.bytes.insert(s.bytes.end(), data.begin(), data.end());
  ++s.fragments;
  s.last = now;
  remember(s, toggle, continued, data);
  if (continued) {
    s.expected_toggle = !toggle;
    // Saturates rather than overflows for a `now` near the end of time.
    s.deadline = now < TimePoint::max() - timeout_ ? now + timeout_ : TimePoint::max();
    if (s.state != State::assembling) {
      s.state = State::assembling;
      set_assembling(index, true);
    }
    return;
  }
  set_assembling(index, false);
  s.state = State::idle;
  s.previous_packet_fragments = s.fragments;
  deliver(index, s.bytes, s.fragments, s.first, s.last, sink);
  s.bytes.clear();
  s.fragments = 0;
}

void PdopReassembler::remember(Stream& s, bool toggle, bool continued,
                               std::span<const std::uint8_t> data) {
  s.has_previous = true;
  s.previous_toggle = toggle;
  s.previous_continued = continued;
  s.previous_length = static_cast<std::uint8_t>(data.size());
  std::copy(data.begin(), data.end(), s.previous.begin());
}

void PdopReassembler::deliver(std::size_t index, std::span<const std::uint8_t> data,
                              std::uint32_t fragments, TimePoint first, TimePoint last, Sink& sink,
                              bool probable_repeat) {
  ++counters_.packets;
  if (fragments == 1) ++counters_.single_frame_packets;
  if (probable_repeat) ++counters_.probable_repeats;
  counters_.packet_bytes += data.size();
  counters_.packet_fragments += fragments;
  Packet packet;
  packet.node = node_of(index);
  packet.tpdo = tpdo_of(index);
  packet.data = data;
  packet.fragments = fragments;
  packet.first = first;
  packet.last = last;
  packet.probable_repeat = probable_repeat;
  sink.on_packet(packet);
}

bool PdopReassembler::repeats_previous(const Stream& s, bool toggle, bool continued,
                                       std::span<const std::uint8_t> data) {
  // While assembling, a toggle error always carries the last accepted fragment's toggle; while
  // idle (t = 1), only a packet that ended on t = 1 can have been repeated.
  return s.has_previous && s.previous_toggle == toggle && s.previous_continued == continued &&
         s.previous_length == data.size() &&
         std::equal(data.begin(), data.end(), s.previous.begin());
}

void PdopReassembler::fail(std::size_t index, Reason reason, TimePoint now, Sink& sink,
                           bool offending, bool continued) {
  Stream& s = streams_[index];
  const bool open = s.state == State::assembling;
  Discard d;
  d.node = node_of(index);
  d.tpdo = tpdo_of(index);
  d.reason = reason;
  d.fragments = open ? s.fragments : 0;
  d.bytes = open ? s.bytes.size() : 0;
  d.first = open ? s.first : now;
  d.last = open ? s.last : now;
  d.at = now;
  ++counters_.discards[static_cast<std::size_t>(reason)];
  counters_.discarded_fragments += d.fragments;
  counters_.discarded_bytes += d.bytes;
  if (open) set_assembling(index, false);
  s.bytes.clear();
  s.fragments = 0;
  s.has_previous = false;
  if (offending) ++counters_.dropped_frames;
  s.state = offending && !continued ? State::idle : State::resynchronising;
  sink.on_discard(d);
}

void PdopReassembler::set_assembling(std::size_t index, bool on) {
  const std::uint64_t bit = std::uint64_t{1} << (index % 64);
  if (on) {
    assembling_[index / 64] |= bit;
  } else {
    assembling_[index / 64] &= ~bit;
  }
}

void PdopReassembler::tick(TimePoint now, Sink& sink) {
  for (std::size_t word = 0; word < assembling_.size(); ++word) {
    std::uint64_t bits = assembling_[word];
    while (bits != 0) {
      const std::size_t index = word * 64 + static_cast<std::size_t>(std::countr_zero(bits));
      bits &= bits - 1;
      if (now >= streams_[index].deadline) fail(index, Reason::timeout, now, sink, false, false);
    }
  }
}

std::optional<PdopReassembler::TimePoint> PdopReassembler::next_deadline() const {
  std::optional<TimePoint> earliest;
  for (std::size_t word = 0; word < assembling_.size(); ++word) {
    std::uint64_t bits = assembling_[word];
    while (bits != 0) {
      const std::size_t index = word * 64 + static_cast<std::size_t>(std::countr_zero(bits));
      bits &= bits - 1;
      if (!earliest || streams_[index].deadline < *earliest) earliest = streams_[index].deadline;
    }
  }
  return earliest;
}

void PdopReassembler::on_node_restart(NodeId node, TimePoint now, Sink& sink) {
  if (node < 1 || node > kMaxNode) return;
  for (unsigned tpdo = 1; tpdo <= kTpdoCount; ++tpdo) {
    const std::size_t index = stream_index(node, tpdo);
    Stream& s = streams_[index];
    if (s.state == State::assembling) {
      // A packet already late is a timeout, as on_frame() would have found it.
      fail(index, now >= s.deadline ? Reason::timeout : Reason::node_restart, now, sink, false,
           false);
    }
    s.state = State::idle;
    s.has_previous = false;
  }
}

void PdopReassembler::on_frames_lost(TimePoint now, Sink& sink) {
  for (std::size_t index = 0; index < kStreamCount; ++index) {
    Stream& s = streams_[index];
    if (s.state == State::assembling) {
      fail(index, now >= s.deadline ? Reason::timeout : Reason::frames_lost, now, sink, false,
           false);
    }
    s.state = State::resynchronising;
    s.has_previous = false;
  }
}

PdopReassembler::State PdopReassembler::state(NodeId node, unsigned tpdo) const {
  if (node < 1 || node > kMaxNode || tpdo < 1 || tpdo > kTpdoCount) return State::idle;
  return streams_[stream_index(node, tpdo)].state;
}

std::size_t PdopReassembler::assembling() const {
  return static_cast<std::size_t>(std::popcount(assembling_[0]) + std::popcount(assembling_[1]));
}

std::uint64_t PdopReassembler::pending_fragments() const {
  std::uint64_t total = 0;
  for (const Stream& s : streams_) {
    if (s.state == State::assembling) total += s.fragments;
  }
  return total;
}

std::size_t PdopReassembler::buffer_capacity() const {
  std::size_t total = 0;
  for (const Stream& s : streams_) total += s.bytes.capacity();
  return total;
}

const char* to_string(PdopReassembler::Reason reason) {
  switch (reason) {
    case PdopReassembler::Reason::missing_fragment:
      return "missing_fragment";
    case PdopReassembler::Reason::duplicate:
      return "duplicate";
    case PdopReassembler::Reason::timeout:
      return "timeout";
    case PdopReassembler::Reason::oversize:
      return "oversize";
    case PdopReassembler::Reason::short_fragment:
      return "short_fragment";
    case PdopReassembler::Reason::empty_frame:
      return "empty_frame";
    case PdopReassembler::Reason::node_restart:
      return "node_restart";
    case PdopReassembler::Reason::frames_lost:
      return "frames_lost";
  }
  return "?";
}

std::string to_string(const PdopReassembler::Discard& d) {
  std::string s = "node " + std::to_string(d.node) + " TPDO" + std::to_string(d.tpdo) + ": ";
  if (d.fragments == 0) {
    return s + "frame refused (" + to_string(d.reason) + ") with no packet open";
  }
  return s + "packet discarded (" + to_string(d.reason) + ") after " + std::to_string(d.fragments) +
         (d.fragments == 1 ? " fragment, " : " fragments, ") + std::to_string(d.bytes) + " bytes";
}

}  // namespace canbridge::bridge
