// libFuzzer target: PdopReassembler (TPDOP reassembly, docs/pdop.md section 3) on an arbitrary
// sequence of module-bus frames, time steps, timer ticks, node restarts and frame-loss marks. Also
// linked into bridge_unit_tests, which feeds it seeded random inputs (PdopReassemblerFuzz.*).
//
// Input: byte 0 picks max_packet_bytes (1 + 2 * byte: 1..511), byte 1 fragment_timeout
// (1 + byte mod 200 ms), then operations of 4 bytes [ctrl, arg, pattern, step]:
//   ctrl bits 0-1: TPDO 1..4; bits 2-3: node (1, 2, 31, 16); bit 4: t; bit 5: c;
//   ctrl bits 6-7, what to do:
//     0, 1: one frame on that TPDO COB-ID with t and c; length arg mod 16 (9..15 as 8), data
//           bytes pattern + i;
//     2:    a whole packet made by canopen::pdop::fragment(), 1 + 2 * arg + (pattern & 1)
//           bytes (the t and c bits of ctrl are ignored);
//     3:    arg mod 4: 0: another frame (mostly no TPDOP fragment: RPDO, SDO, heartbeat,
//           acknowledgement, extended, error, node 0; or any standard id pattern x 8);
//           1: on_node_restart(node); 2: tick() at now; 3: by arg bits 2-3: 1: on_frames_lost()
//           (the bus lost frames), 2: the last frame fed again (CAN's double reception, e.g. a
//           whole packet's last fragment: a probable_repeat when it is a one-frame packet), 0
//           and 3: a remote frame on the TPDO COB-ID (before 3 was always the remote frame:
//           older inputs mostly keep their meaning);
//   step (low 4 bits) advances the time first: 0, 0, 0, 0, 1 us, 100 us, 1 ms, 5 ms, 20 ms,
//   timeout - 1 ms, timeout, timeout + 1 ms, 2 x timeout, 50 ms, 250 ms, 1 s.
//
// Invariants:
// - The reassembler (its timer ticked exactly at next_deadline(), as the gateway does) reports
//   the same packets and discards, in the same order and with the same fields, as a plain
//   reference model written from docs/pdop.md section 3, and has the same per-stream states
//   and next deadline after every operation. The model flags probable_repeat on its own (a
//   one-frame packet equal to the last fragment of the stream's previous, multi-fragment packet,
//   within kRepeatWindow of it, with no discard, restart or frame loss in between), and its
//   tallies equal the reassembler's counters at the end.
// - A second reassembler that is never ticked (timeouts found on the next fragment only) ends,
//   after a final tick, with the same per-stream packets and discards (all but the detection
//   time), the same counters and stream states: the timer changes when a timeout is reported,
//   nothing else.
// - Every packet has 1..max_packet_bytes bytes in ceil(size / 8) fragments; every discarded
//   partial packet holds 8 bytes per fragment; the counters account for every frame taken; the
//   buffers never exceed 124 x max_packet_bytes.
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "can/frame.hpp"
#include "canopen/pdop.hpp"
#include "routing/pdop_reassembler.hpp"

namespace {

using namespace std::chrono_literals;
using canbridge::bridge::PdopReassembler;
using canbridge::bridge::PdopReassemblerOptions;
using canbridge::can::Frame;
using canbridge::can::FrameFlags;
using Reason = PdopReassembler::Reason;
using State = PdopReassembler::State;
using TimePoint = PdopReassembler::TimePoint;
using Duration = PdopReassembler::Clock::duration;
namespace pdop = canbridge::canopen::pdop;

void require(bool holds, const char* invariant) {
  if (holds) return;
  std::fprintf(stderr, "fuzz invariant violated: %s\n", invariant);
  std::abort();
}

// One reported result, owning its bytes.
struct Event {
  bool packet = false;
  unsigned node = 0;
  unsigned tpdo = 0;
  Reason reason = Reason::missing_fragment;
  std::vector<std::uint8_t> data;
  std::uint32_t fragments = 0;
  std::size_t bytes = 0;
  TimePoint first{};
  TimePoint last{};
  TimePoint at{};                // discards only
  bool probable_repeat = false;  // packets only
  bool same_but_time_seen(const Event& o) const {
    return packet == o.packet && node == o.node && tpdo == o.tpdo && reason == o.reason &&
           data == o.data && fragments == o.fragments && bytes == o.bytes && first == o.first &&
           last == o.last && probable_repeat == o.probable_repeat;
  }
  bool operator==(const Event& o) const { return same_but_time_seen(o) && at == o.at; }
};

class Recorder : public PdopReassembler::Sink {
 public:
  explicit Recorder(std::size_t max_packet_bytes) : max_(max_packet_bytes) {}
  void on_packet(const PdopReassembler::Packet& p) override {
    require(!p.data.empty() && p.data.size() <= max_, "packet size outside 1..max_packet_bytes");
    require(p.fragments == (p.data.size() + 7) / 8, "packet fragments != ceil(size / 8)");
    require(p.node >= 1 && p.node <= 31 && p.tpdo >= 1 && p.tpdo <= 4, "packet stream range");
    require(p.first <= p.last, "packet first after last");
    require(!p.probable_repeat || p.fragments == 1, "probable_repeat on a multi-fragment packet");
    Event e;
    e.packet = true;
    e.node = p.node;
    e.tpdo = p.tpdo;
    e.data.assign(p.data.begin(), p.data.end());
    e.fragments = p.fragments;
    e.bytes = p.data.size();
    e.first = p.first;
    e.last = p.last;
    e.probable_repeat = p.probable_repeat;
    events.push_back(std::move(e));
  }
  void on_discard(const PdopReassembler::Discard& d) override {
    require(d.bytes == 8 * std::size_t{d.fragments}, "discarded partial packet not 8 bytes/frag");
    require(d.bytes <= max_, "discarded partial packet larger than max_packet_bytes");
    require(d.node >= 1 && d.node <= 31 && d.tpdo >= 1 && d.tpdo <= 4, "discard stream range");
    require(d.first <= d.last && d.last <= d.at, "discard times out of order");
    Event e;
    e.node = d.node;
    e.tpdo = d.tpdo;
    e.reason = d.reason;
    e.fragments = d.fragments;
    e.bytes = d.bytes;
    e.first = d.first;
    e.last = d.last;
    e.at = d.at;
    events.push_back(std::move(e));
  }
  std::vector<Event> events;

 private:
  std::size_t max_;
};

// docs/pdop.md section 3, written out as plainly as possible: one map entry per (node, TPDO).
class Model {
 public:
  Model(std::size_t max_packet_bytes, Duration timeout) : max_(max_packet_bytes), t_(timeout) {}

  // True when the frame is a TPDOP frame: a standard data frame on a TPDO COB-ID of a node.
  bool frame(const Frame& f, TimePoint now) {
    if (f.is_extended() || f.is_remote() || f.is_error()) return false;
    const pdop::FragmentId id = pdop::decode(f.id);
    const auto tpdo = pdop::tpdo_number(id.function_code);
    if (!tpdo || id.node < 1 || id.node > 31) return false;
    ++frames;
    take(id, *tpdo, f, now);
    return true;
  }

  void take(const pdop::FragmentId& id, unsigned tpdo, const Frame& f, TimePoint now) {
    const Key key{id.node, tpdo};
    S& s = streams_[key];
    const std::vector<std::uint8_t> data(f.data.begin(), f.data.begin() + f.len);
    if (s.state == State::assembling && now - s.last >= t_) {
      report(key, Reason::timeout, now);
      s.state = State::resynchronising;
    }
    if (s.state == State::resynchronising) {
      ++dropped;
      if (!id.continued) s.state = State::idle;
      return;
    }
    if (data.empty() && !id.continued) return refuse(key, Reason::empty_frame, false, now);
    const bool expected = s.state == State::assembling ? s.expected_toggle : false;
    if (id.toggle != expected) {
      const bool repeat = s.previous && s.previous->toggle == id.toggle &&
                          s.previous->continued == id.continued && s.previous->data == data;
      return refuse(key, repeat ? Reason::duplicate : Reason::missing_fragment, id.continued, now);
    }
    if (s.state == State::idle) {
      s.bytes.clear();
      s.fragments = 0;
      s.first = now;
      s.previous.reset();
    }
    if (id.continued && data.size() < 8) {
      return refuse(key, Reason::short_fragment, id.continued, now);
    }
    if (s.bytes.size() + data.size() > max_) {
      return refuse(key, Reason::oversize, id.continued, now);
    }
    s.bytes.insert(s.bytes.end(), data.begin(), data.end());
    ++s.fragments;
    s.last = now;
    s.previous = Fragment{id.toggle, id.continued, data};
    if (id.continued) {
      s.state = State::assembling;
      s.expected_toggle = !id.toggle;
      return;
    }
    s.state = State::idle;
    // docs/pdop.md section 7: a one-frame packet that is the previous packet's last fragment
    // again (double reception), soon after it. Only a last fragment with t = 0 can pass as a
    // one-frame packet; the comparison with the whole fragment says so too.
    const bool probable_repeat = s.fragments == 1 && s.delivered && s.delivered->fragments > 1 &&
                                 s.delivered->fragment == *s.previous &&
                                 now - s.delivered->last <= PdopReassembler::kRepeatWindow;
    s.delivered = Delivered{s.fragments, s.last, *s.previous};
    Event e;
    e.packet = true;
    e.node = key.first;
    e.tpdo = key.second;
    e.data = s.bytes;
    e.fragments = s.fragments;
    e.bytes = s.bytes.size();
    e.first = s.first;
    e.last = s.last;
    e.probable_repeat = probable_repeat;
    events.push_back(std::move(e));
  }

  void tick(TimePoint now) {
    for (auto& [key, s] : streams_) {
      if (s.state == State::assembling && now - s.last >= t_) {
        report(key, Reason::timeout, now);
        s.state = State::resynchronising;
      }
    }
  }

  void restart(unsigned node, TimePoint now) {
    for (unsigned tpdo = 1; tpdo <= 4; ++tpdo) {
      const Key key{node, tpdo};
      S& s = streams_[key];
      if (s.state == State::assembling) {
        report(key, now - s.last >= t_ ? Reason::timeout : Reason::node_restart, now);
      }
      s.state = State::idle;
      s.previous.reset();
      s.delivered.reset();
    }
  }

  // Every stream, in index order (node, then TPDO): an open packet is discarded, and every
  // stream, idle or not, drops frames up to its next c = 0 frame.
  void frames_lost(TimePoint now) {
    for (unsigned node = 1; node <= 31; ++node) {
      for (unsigned tpdo = 1; tpdo <= 4; ++tpdo) {
        const Key key{node, tpdo};
        S& s = streams_[key];
        if (s.state == State::assembling) {
          report(key, now - s.last >= t_ ? Reason::timeout : Reason::frames_lost, now);
        }
        s.state = State::resynchronising;
        s.previous.reset();
        s.delivered.reset();
      }
    }
  }

  std::optional<TimePoint> next_deadline() const {
    std::optional<TimePoint> earliest;
    for (const auto& [key, s] : streams_) {
      if (s.state != State::assembling) continue;
      if (!earliest || s.last + t_ < *earliest) earliest = s.last + t_;
    }
    return earliest;
  }

  State state(unsigned node, unsigned tpdo) const {
    const auto it = streams_.find(Key{node, tpdo});
    return it == streams_.end() ? State::idle : it->second.state;
  }

  std::vector<Event> events;
  std::uint64_t frames = 0;   // TPDOP frames taken
  std::uint64_t dropped = 0;  // offending frames and frames dropped while resynchronising

 private:
  using Key = std::pair<unsigned, unsigned>;
  struct Fragment {
    bool toggle = false;
    bool continued = false;
    std::vector<std::uint8_t> data;
    bool operator==(const Fragment&) const = default;
  };
  struct Delivered {
    std::uint32_t fragments = 0;
    TimePoint last{};   // time of its last fragment
    Fragment fragment;  // its last fragment
  };
  struct S {
    State state = State::idle;
    bool expected_toggle = false;
    std::vector<std::uint8_t> bytes;
    std::uint32_t fragments = 0;
    TimePoint first{};
    TimePoint last{};
    std::optional<Fragment> previous;    // the last accepted fragment
    std::optional<Delivered> delivered;  // the last packet, until a discard, restart or loss
  };

  // A discard of whatever the stream has open; the caller sets the state after.
  void report(const Key& key, Reason reason, TimePoint now) {
    S& s = streams_[key];
    const bool open = s.state == State::assembling;
    Event e;
    e.node = key.first;
    e.tpdo = key.second;
    e.reason = reason;
    e.fragments = open ? s.fragments : 0;
    e.bytes = open ? s.bytes.size() : 0;
    e.first = open ? s.first : now;
    e.last = open ? s.last : now;
    e.at = now;
    events.push_back(std::move(e));
    s.bytes.clear();
    s.fragments = 0;
    s.previous.reset();
    s.delivered.reset();
  }
  // The offending frame ends the broken packet when it has c = 0 (section 3).
  void refuse(const Key& key, Reason reason, bool continued, TimePoint now) {
    ++dropped;
    report(key, reason, now);
    streams_[key].state = continued ? State::resynchronising : State::idle;
  }

  std::size_t max_;
  Duration t_;
  std::map<Key, S> streams_;
};

void check_accounting(const PdopReassembler& r) {
  const auto& c = r.counters();
  require(c.frames ==
              c.packet_fragments + c.discarded_fragments + c.dropped_frames + r.pending_fragments(),
          "counters do not account for every frame");
  require(r.buffer_capacity() <= PdopReassembler::kStreamCount * r.options().max_packet_bytes,
          "buffers above 124 x max_packet_bytes");
  std::uint64_t discards = 0;
  for (auto n : c.discards) discards += n;
  require(discards == c.discards_total(), "discards_total");
}

bool same_counters(const PdopReassembler::Counters& a, const PdopReassembler::Counters& b) {
  return a.frames == b.frames && a.packets == b.packets &&
         a.single_frame_packets == b.single_frame_packets &&
         a.probable_repeats == b.probable_repeats && a.packet_bytes == b.packet_bytes &&
         a.packet_fragments == b.packet_fragments && a.discards == b.discards &&
         a.discarded_fragments == b.discarded_fragments && a.discarded_bytes == b.discarded_bytes &&
         a.dropped_frames == b.dropped_frames;
}

// The counters the model's results add up to, once nothing is pending.
PdopReassembler::Counters tally(const Model& model) {
  PdopReassembler::Counters c;
  c.frames = model.frames;
  c.dropped_frames = model.dropped;
  for (const Event& e : model.events) {
    if (e.packet) {
      ++c.packets;
      if (e.fragments == 1) ++c.single_frame_packets;
      if (e.probable_repeat) ++c.probable_repeats;
      c.packet_bytes += e.bytes;
      c.packet_fragments += e.fragments;
    } else {
      ++c.discards[static_cast<std::size_t>(e.reason)];
      c.discarded_fragments += e.fragments;
      c.discarded_bytes += e.bytes;
    }
  }
  return c;
}

std::vector<Event> of_stream(const std::vector<Event>& events, unsigned node, unsigned tpdo) {
  std::vector<Event> out;
  for (const Event& e : events) {
    if (e.node == node && e.tpdo == tpdo) out.push_back(e);
  }
  return out;
}

Frame other_frame(std::uint8_t ctrl, std::uint8_t pattern) {
  // Frames the reassembler must leave alone.
  const std::uint32_t base = pdop::tpdo_base((ctrl & 3u) + 1);
  switch (pattern % 8) {
    case 0:  // RPDO of the same node, any t/c
      return Frame::standard(base + 0x80u + (ctrl & 0x7Fu), {1, 2, 3});
    case 1:  // a TPDO COB-ID with node 0
      return Frame::standard(base | (ctrl & 0x60u), {pattern});
    case 2:  // extended id with a TPDO-looking low part
      return Frame::make(base | 0x25u, FrameFlags::extended, {1, 2, 3, 4, 5, 6, 7, 8});
    case 3:  // error frame
      return Frame::make(base | 0x05u, FrameFlags::error, {0, 0, 0, 0, 0, 0, 0, 0});
    case 4:  // heartbeat, SDO, EMCY, RPDOP acknowledgement, NMT
      return Frame::standard(0x700u + (ctrl & 0x1Fu), {0x05});
    case 5:
      return Frame::standard(0x580u + (ctrl & 0x7Fu), {0x43, 0, 0x10, 0, 1, 2, 3, 4});
    case 6:
      return pdop::encode_ack(static_cast<std::uint8_t>(1 + ctrl % 31), pdop::Ack{1});
    default:  // anything: the model decides whether it is a fragment
      return Frame::standard(std::uint32_t{pattern} << 3, {pattern});
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  PdopReassemblerOptions options;
  options.max_packet_bytes = 1 + 2 * std::size_t{data[0]};
  options.fragment_timeout = std::chrono::milliseconds(1 + data[1] % 200);
  const Duration timeout = options.fragment_timeout;
  PdopReassembler timed(options);
  PdopReassembler untimed(options);
  Model model(options.max_packet_bytes, timeout);
  Recorder timed_out(options.max_packet_bytes);
  Recorder untimed_out(options.max_packet_bytes);
  static constexpr unsigned kNodes[4] = {1, 2, 31, 16};
  const Duration steps[16] = {0us,   0us,  0us,           0us,     1us,           100us,       1ms,
                              5ms,   20ms, timeout - 1ms, timeout, timeout + 1ms, 2 * timeout, 50ms,
                              250ms, 1s};
  TimePoint now = TimePoint{} + 1h;

  // The gateway's one timer: fires at next_deadline(), before anything later is read.
  const auto run_timer = [&](TimePoint until) {
    while (const auto deadline = timed.next_deadline()) {
      require(deadline == model.next_deadline(), "next_deadline differs from the model");
      if (*deadline > until) break;
      const std::size_t before = timed_out.events.size();
      timed.tick(*deadline, timed_out);
      model.tick(*deadline);
      require(timed_out.events.size() > before, "tick at next_deadline() reported nothing");
    }
    require(!model.next_deadline() || timed.next_deadline(), "model has a deadline, not the code");
  };
  std::optional<Frame> last_fed;  // for the double reception operation
  // Every stream's state (all 124: a frame loss touches every one) is the model's.
  const auto require_same_states = [&](const char* invariant) {
    for (unsigned n = 1; n <= PdopReassembler::kMaxNode; ++n) {
      for (unsigned t = 1; t <= PdopReassembler::kTpdoCount; ++t) {
        require(timed.state(static_cast<std::uint8_t>(n), t) == model.state(n, t), invariant);
      }
    }
  };
  const auto feed = [&](const Frame& f) {
    last_fed = f;
    run_timer(now);
    const bool taken_timed = timed.on_frame(f, now, timed_out);
    const bool taken_untimed = untimed.on_frame(f, now, untimed_out);
    require(taken_timed == taken_untimed, "on_frame taken differs between two reassemblers");
    require(taken_timed == model.frame(f, now), "on_frame taken differs from the model");
    return taken_timed;
  };

  std::size_t checked = 0;  // events already compared with the model
  std::span<const std::uint8_t> ops(data + 2, size - 2);
  for (; ops.size() >= 4; ops = ops.subspan(4)) {
    const std::uint8_t ctrl = ops[0];
    const std::uint8_t arg = ops[1];
    const std::uint8_t pattern = ops[2];
    now += steps[ops[3] & 0x0F];
    const unsigned tpdo = (ctrl & 3u) + 1;
    const auto node = static_cast<std::uint8_t>(kNodes[(ctrl >> 2) & 3u]);
    const std::uint16_t base = pdop::tpdo_base(tpdo);
    switch (ctrl >> 6) {
      case 0:
      case 1: {
        std::uint8_t bytes[8];
        for (unsigned i = 0; i < 8; ++i) bytes[i] = static_cast<std::uint8_t>(pattern + i);
        const std::size_t length = std::min<std::size_t>(arg & 0x0Fu, 8);
        const pdop::FragmentId id{static_cast<std::uint8_t>(base >> 7), (ctrl & 0x10u) != 0,
                                  (ctrl & 0x20u) != 0, node};
        feed(Frame::from_span(pdop::encode(id), std::span<const std::uint8_t>(bytes, length)));
        break;
      }
      case 2: {
        std::vector<std::uint8_t> packet(1 + 2 * std::size_t{arg} + (pattern & 1u));
        for (std::size_t i = 0; i < packet.size(); ++i) {
          packet[i] = static_cast<std::uint8_t>(pattern * 31 + i);
        }
        for (const Frame& f : pdop::fragment(base, node, packet)) feed(f);
        break;
      }
      default:
        switch (arg & 3u) {
          case 0:
            feed(other_frame(ctrl, pattern));
            break;
          case 1:
            run_timer(now);
            timed.on_node_restart(node, now, timed_out);
            untimed.on_node_restart(node, now, untimed_out);
            model.restart(node, now);
            break;
          case 2:
            run_timer(now);
            timed.tick(now, timed_out);
            model.tick(now);
            break;
          default:
            switch ((arg >> 2) & 3u) {
              case 1:
                run_timer(now);
                timed.on_frames_lost(now, timed_out);
                untimed.on_frames_lost(now, untimed_out);
                model.frames_lost(now);
                for (unsigned n = 1; n <= PdopReassembler::kMaxNode; ++n) {
                  for (unsigned t = 1; t <= PdopReassembler::kTpdoCount; ++t) {
                    require(
                        timed.state(static_cast<std::uint8_t>(n), t) == State::resynchronising &&
                            untimed.state(static_cast<std::uint8_t>(n), t) ==
                                State::resynchronising,
                        "a stream not resynchronising after on_frames_lost");
                  }
                }
                require(timed.assembling() == 0 && untimed.assembling() == 0,
                        "packets left open after on_frames_lost");
                require_same_states("stream state after on_frames_lost differs from the model");
                break;
              case 2:
                if (last_fed) {
                  const Frame again = *last_fed;
                  feed(again);
                  break;
                }
                [[fallthrough]];
              default: {
                const Frame f = Frame::make(base | 0x20u | node, FrameFlags::remote, {});
                require(!feed(f), "a remote frame was taken");
                break;
              }
            }
            break;
        }
        break;
    }
    require(timed_out.events.size() == model.events.size() &&
                std::equal(timed_out.events.begin() + static_cast<std::ptrdiff_t>(checked),
                           timed_out.events.end(),
                           model.events.begin() + static_cast<std::ptrdiff_t>(checked)),
            "events differ from the reference model");
    checked = model.events.size();
    for (unsigned n : kNodes) {
      for (unsigned t = 1; t <= 4; ++t) {
        require(timed.state(static_cast<std::uint8_t>(n), t) == model.state(n, t),
                "stream state differs from the model");
      }
    }
    check_accounting(timed);
    check_accounting(untimed);
  }

  // Far enough for every deadline: both report every timeout left.
  now += 20s;
  timed.tick(now, timed_out);
  untimed.tick(now, untimed_out);
  model.tick(now);
  require(timed_out.events == model.events, "final events differ from the reference model");
  require(timed.assembling() == 0 && untimed.assembling() == 0, "packets left after the end");
  require(same_counters(timed.counters(), tally(model)), "counters differ from the model's tally");
  require(same_counters(timed.counters(), untimed.counters()),
          "counters depend on when the timer ticked");
  require_same_states("final stream state differs from the model");
  for (unsigned n = 1; n <= PdopReassembler::kMaxNode; ++n) {
    for (unsigned t = 1; t <= PdopReassembler::kTpdoCount; ++t) {
      require(timed.state(static_cast<std::uint8_t>(n), t) ==
                  untimed.state(static_cast<std::uint8_t>(n), t),
              "final stream state depends on when the timer ticked");
    }
  }
  for (unsigned n : kNodes) {
    for (unsigned t = 1; t <= 4; ++t) {
      const auto a = of_stream(timed_out.events, n, t);
      const auto b = of_stream(untimed_out.events, n, t);
      require(a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(),
                                                 [](const Event& x, const Event& y) {
                                                   return x.same_but_time_seen(y);
                                                 }),
              "results depend on when the timer ticked");
    }
  }
  return 0;
}
