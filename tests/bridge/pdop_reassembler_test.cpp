// TPDOP reassembly (docs/pdop.md section 3): fragments of one pdop module bus in, packets and
// discards out, with injected times. The doc's example, every discard reason, the timer, limits,
// edge node ids, frames that are not fragments, the loss patterns one toggle bit cannot see, and
// a property test: random sizes, interleaving, loss, repetition, gaps and oversize against an
// oracle computed from what was sent. PdopReassemblerFuzz.* runs the libFuzzer target
// (tests/fuzz/pdop_reassembler_fuzz.cpp: a reference model and invariants) on random inputs.
#include "routing/pdop_reassembler.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <map>
#include <optional>
#include <ostream>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "canopen/pdop.hpp"

#if defined(__SANITIZE_ADDRESS__)
#define PDOP_REASSEMBLER_COUNTS_ALLOCATIONS 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define PDOP_REASSEMBLER_COUNTS_ALLOCATIONS 1
#endif
#endif

#ifdef PDOP_REASSEMBLER_COUNTS_ALLOCATIONS
extern "C" int __sanitizer_install_malloc_and_free_hooks(void (*)(const volatile void*,
                                                                  std::size_t),
                                                         void (*)(const volatile void*));
#endif

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace canbridge::bridge {

void PrintTo(PdopReassembler::Reason reason, std::ostream* os) {
  *os << to_string(reason);
}

namespace {

using namespace std::chrono_literals;
using can::Frame;
using Reason = PdopReassembler::Reason;
using State = PdopReassembler::State;
using TimePoint = PdopReassembler::TimePoint;
using Bytes = std::vector<std::uint8_t>;
namespace pdop = canopen::pdop;

const TimePoint kReassemblyStart = TimePoint{} + 1000s;

struct Got {
  bool packet = false;
  unsigned node = 0;
  unsigned tpdo = 0;
  Bytes data;
  std::uint32_t fragments = 0;
  TimePoint first{};
  TimePoint last{};
  bool probable_repeat = false;
  PdopReassembler::Discard discard{};
};

std::ostream& operator<<(std::ostream& os, const Got& g) {
  if (g.packet) {
    return os << "packet node " << g.node << " TPDO" << g.tpdo << " " << g.data.size() << " bytes";
  }
  return os << to_string(g.discard);
}

class Recorder : public PdopReassembler::Sink {
 public:
  void on_packet(const PdopReassembler::Packet& p) override {
    Got g;
    g.packet = true;
    g.node = p.node;
    g.tpdo = p.tpdo;
    g.data.assign(p.data.begin(), p.data.end());
    g.fragments = p.fragments;
    g.first = p.first;
    g.last = p.last;
    g.probable_repeat = p.probable_repeat;
    got.push_back(std::move(g));
  }
  void on_discard(const PdopReassembler::Discard& d) override {
    Got g;
    g.node = d.node;
    g.tpdo = d.tpdo;
    g.discard = d;
    got.push_back(std::move(g));
  }
  std::vector<Got> take() { return std::exchange(got, {}); }
  std::vector<Got> got;
};

Bytes counting(std::size_t size, std::uint8_t from = 0) {
  Bytes b(size);
  for (std::size_t i = 0; i < size; ++i) b[i] = static_cast<std::uint8_t>(from + i);
  return b;
}

std::vector<Frame> fragments(unsigned tpdo, unsigned node, const Bytes& packet) {
  return pdop::fragment(pdop::tpdo_base(tpdo), static_cast<canopen::NodeId>(node), packet);
}

// A frame on TPDO `tpdo` of `node` with the given t, c and bytes.
Frame fragment_frame(unsigned tpdo, unsigned node, bool t, bool c, const Bytes& data) {
  const pdop::FragmentId id{static_cast<std::uint8_t>(pdop::tpdo_base(tpdo) >> 7), t, c,
                            static_cast<canopen::NodeId>(node)};
  return Frame::from_span(pdop::encode(id), data);
}

struct ReassemblerRig {
  explicit ReassemblerRig(PdopReassemblerOptions options = {}) : r(options) {}
  // Feeds the frames 1 ms apart from `at`; returns what came out.
  std::vector<Got> feed(const std::vector<Frame>& frames, TimePoint at = kReassemblyStart,
                        std::chrono::microseconds step = 1ms) {
    for (const Frame& f : frames) {
      EXPECT_TRUE(r.on_frame(f, at, sink)) << can::to_string(f);
      at += step;
    }
    return sink.take();
  }
  std::vector<Got> tick(TimePoint at) {
    r.tick(at, sink);
    return sink.take();
  }
  void expect_accounted() const {
    const auto& c = r.counters();
    EXPECT_EQ(c.frames, c.packet_fragments + c.discarded_fragments + c.dropped_frames +
                            r.pending_fragments());
  }
  PdopReassembler r;
  Recorder sink;
};

void expect_discard(const Got& g, unsigned node, unsigned tpdo, Reason reason,
                    std::uint32_t fragments) {
  ASSERT_FALSE(g.packet) << g;
  EXPECT_EQ(g.discard.node, node);
  EXPECT_EQ(g.discard.tpdo, tpdo);
  EXPECT_EQ(g.discard.reason, reason);
  EXPECT_EQ(g.discard.fragments, fragments);
  EXPECT_EQ(g.discard.bytes, 8u * fragments);
}

void expect_packet(const Got& g, unsigned node, unsigned tpdo, const Bytes& data) {
  ASSERT_TRUE(g.packet) << g;
  EXPECT_EQ(g.node, node);
  EXPECT_EQ(g.tpdo, tpdo);
  EXPECT_EQ(g.data, data);
  EXPECT_EQ(g.fragments, (data.size() + 7) / 8);
}

// --- options ---------------------------------------------------------------------------------

TEST(PdopReassemblerOptions, DefaultsAreTheDocsSection5) {
  const PdopReassemblerOptions o;
  EXPECT_EQ(o.max_packet_bytes, 4096u);
  EXPECT_EQ(o.fragment_timeout, 100ms);
  EXPECT_EQ(o.validate(), std::nullopt);
  PdopReassembler r;
  EXPECT_EQ(r.options().max_packet_bytes, 4096u);
}

TEST(PdopReassemblerOptions, RangesAreValidatedNamingTheField) {
  PdopReassemblerOptions o;
  o.max_packet_bytes = 0;
  EXPECT_EQ(o.validate(), "max_packet_bytes: 0 is outside 1..524280");
  o.max_packet_bytes = 524281;
  EXPECT_EQ(o.validate(), "max_packet_bytes: 524281 is outside 1..524280");
  EXPECT_THROW(PdopReassembler{o}, std::invalid_argument);
  o.max_packet_bytes = 524280;
  EXPECT_EQ(o.validate(), std::nullopt);
  o.max_packet_bytes = 1;
  EXPECT_EQ(o.validate(), std::nullopt);
  o.fragment_timeout = 0ms;
  EXPECT_EQ(o.validate(), "fragment_timeout: 0 ms is outside 1..10000 ms");
  EXPECT_THROW(PdopReassembler{o}, std::invalid_argument);
  o.fragment_timeout = 10001ms;
  EXPECT_TRUE(o.validate().has_value());
  o.fragment_timeout = 10000ms;
  EXPECT_EQ(o.validate(), std::nullopt);
  o.fragment_timeout = 1ms;
  EXPECT_EQ(o.validate(), std::nullopt);
}

// --- packets ---------------------------------------------------------------------------------

TEST(PdopReassembler, TheDocsTwentyByteExampleIsOnePacket) {
  // docs/pdop.md section 6: 1A5#0001020304050607, 1E5#08090A0B0C0D0E0F, 185#10111213.
  ReassemblerRig rig;
  const std::vector<Frame> frames{Frame::standard(0x1A5, {0, 1, 2, 3, 4, 5, 6, 7}),
                                  Frame::standard(0x1E5, {8, 9, 10, 11, 12, 13, 14, 15}),
                                  Frame::standard(0x185, {16, 17, 18, 19})};
  ASSERT_EQ(frames, fragments(1, 5, counting(20)));
  rig.r.on_frame(frames[0], kReassemblyStart, rig.sink);
  EXPECT_EQ(rig.r.state(5, 1), State::assembling);
  EXPECT_EQ(rig.r.assembling(), 1u);
  EXPECT_EQ(rig.r.pending_fragments(), 1u);
  rig.r.on_frame(frames[1], kReassemblyStart + 1ms, rig.sink);
  EXPECT_TRUE(rig.sink.got.empty());
  rig.r.on_frame(frames[2], kReassemblyStart + 2ms, rig.sink);
  const auto got = rig.sink.take();
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, counting(20));
  EXPECT_EQ(got[0].first, kReassemblyStart);
  EXPECT_EQ(got[0].last, kReassemblyStart + 2ms);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);
  const auto& c = rig.r.counters();
  EXPECT_EQ(c.packets, 1u);
  EXPECT_EQ(c.packet_bytes, 20u);
  EXPECT_EQ(c.packet_fragments, 3u);
  EXPECT_EQ(c.frames, 3u);
  EXPECT_EQ(c.single_frame_packets, 0u);
  EXPECT_EQ(c.discards_total(), 0u);
  rig.expect_accounted();
}

TEST(PdopReassembler, APlainPdoIsAOneFramePacket) {
  ReassemblerRig rig;
  auto got = rig.feed({Frame::standard(0x185, {0xAA, 0xBB, 0xCC})});
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, {0xAA, 0xBB, 0xCC});
  EXPECT_EQ(got[0].fragments, 1u);
  EXPECT_EQ(got[0].first, got[0].last);
  got = rig.feed({Frame::from_span(0x285, counting(8)), Frame::from_span(0x285, counting(8))});
  ASSERT_EQ(got.size(), 2u);  // the same PDO twice is two packets
  expect_packet(got[0], 5, 2, counting(8));
  expect_packet(got[1], 5, 2, counting(8));
  EXPECT_EQ(rig.r.counters().single_frame_packets, 3u);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);
}

TEST(PdopReassembler, PacketsOfEverySizeUpToTheLimitArriveBitExact) {
  PdopReassemblerOptions o;
  o.max_packet_bytes = 70;
  ReassemblerRig rig(o);
  for (std::size_t size = 1; size <= 70; ++size) {
    const Bytes data = counting(size, static_cast<std::uint8_t>(size));
    const auto got = rig.feed(fragments(3, 9, data));
    ASSERT_EQ(got.size(), 1u) << size;
    expect_packet(got[0], 9, 3, data);
  }
  EXPECT_LE(rig.r.buffer_capacity(), 70u);
}

TEST(PdopReassembler, EdgeNodeIds1And31OnTpdo1And4) {
  ReassemblerRig rig;
  for (unsigned node : {1u, 31u}) {
    for (unsigned tpdo : {1u, 4u}) {
      const Bytes data = counting(17, static_cast<std::uint8_t>(node + tpdo));
      const auto frames = fragments(tpdo, node, data);
      ASSERT_EQ(frames.size(), 3u);
      const auto got = rig.feed(frames);
      ASSERT_EQ(got.size(), 1u);
      expect_packet(got[0], node, tpdo, data);
    }
  }
  // Node 31 with t = c = 1 sets every low bit: 0x1FF and 0x4FF are still fragments.
  EXPECT_EQ(fragment_frame(1, 31, true, true, counting(8)).id, 0x1FFu);
  EXPECT_EQ(fragment_frame(4, 31, true, true, counting(8)).id, 0x4FFu);
  EXPECT_EQ(fragment_frame(1, 1, false, false, counting(1)).id, 0x181u);
  EXPECT_EQ(rig.r.counters().packets, 4u);
}

TEST(PdopReassembler, StreamsOfNodesAndTpdosInterleaveFreely) {
  ReassemblerRig rig;
  const Bytes a = counting(40, 0x10), b = counting(33, 0x40), c = counting(9, 0x80),
              d = counting(8, 0xC0);
  const auto fa = fragments(1, 3, a), fb = fragments(2, 3, b), fc = fragments(1, 4, c),
             fd = fragments(4, 31, d);
  // Round robin over the four streams.
  std::vector<Frame> mixed;
  for (std::size_t k = 0; k < 5; ++k) {
    for (const auto* f : {&fa, &fb, &fc, &fd}) {
      if (k < f->size()) mixed.push_back((*f)[k]);
    }
  }
  const auto got = rig.feed(mixed);
  ASSERT_EQ(got.size(), 4u);
  // In completion order: d (1 frame), c (2), b (5, ends in round 4), a (5, ends in round 4).
  expect_packet(got[0], 31, 4, d);
  expect_packet(got[1], 4, 1, c);
  expect_packet(got[2], 3, 1, a);
  expect_packet(got[3], 3, 2, b);
}

TEST(PdopReassembler, FramesThatAreNoFragmentsAreIgnored) {
  ReassemblerRig rig;
  const auto frames = fragments(1, 5, counting(20));
  rig.r.on_frame(frames[0], kReassemblyStart, rig.sink);
  const std::vector<Frame> others{
      Frame::standard(0x000, {0x01, 0x00}),                    // NMT
      Frame::standard(0x080, {}),                              // SYNC
      Frame::standard(0x085, {0, 0, 0, 0, 0, 0, 0, 0}),        // EMCY
      Frame::standard(0x205, {1}),                             // RPDO1 of the same node
      Frame::from_span(0x225, counting(8)),                    // RPDOP fragment, c = 1
      Frame::standard(0x565, {1}),                             // RPDO4, t = 1, c = 1
      Frame::standard(0x585, {0x60, 0, 0x10, 0, 0, 0, 0, 0}),  // SDO
      Frame::standard(0x705, {0x05}),                          // heartbeat
      pdop::encode_ack(5, pdop::Ack{1, pdop::AckStatus::complete, 1, 4}),
      pdop::ack_request(5),
      Frame::standard(0x180, {1}),                      // TPDO1 COB-ID with node 0
      Frame::from_span(0x1E0, counting(8)),             // node 0 with t = c = 1
      Frame::make(0x1E5, can::FrameFlags::remote, {}),  // remote: never a fragment
      Frame::make(0x1E5, can::FrameFlags::extended, {8, 9, 10, 11, 12, 13, 14, 15}),
      Frame::make(0x1E5, can::FrameFlags::error, {0, 0, 0, 0, 0, 0, 0, 0}),
      Frame::standard(0x7E5, {0x04, 1}),  // LSS
  };
  for (const Frame& f : others) {
    EXPECT_FALSE(rig.r.on_frame(f, kReassemblyStart + 1ms, rig.sink)) << can::to_string(f);
  }
  Frame too_long = frames[1];
  too_long.len = 9;  // no classic CAN frame
  EXPECT_FALSE(rig.r.on_frame(too_long, kReassemblyStart + 1ms, rig.sink));
  EXPECT_TRUE(rig.sink.got.empty());
  EXPECT_EQ(rig.r.counters().frames, 1u);
  rig.r.on_frame(frames[1], kReassemblyStart + 2ms, rig.sink);
  rig.r.on_frame(frames[2], kReassemblyStart + 3ms, rig.sink);
  const auto got = rig.sink.take();
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, counting(20));
}

// --- discards --------------------------------------------------------------------------------

TEST(PdopReassembler, ALostMiddleFragmentDiscardsAndResynchronisesAtTheLastFragment) {
  ReassemblerRig rig;
  auto frames = fragments(2, 7, counting(40));  // 5 fragments
  frames.erase(frames.begin() + 2);             // k = 2 lost: k = 3 has t = 1, expected 0
  auto got = rig.feed({frames[0], frames[1], frames[2]});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 7, 2, Reason::missing_fragment, 2);
  EXPECT_EQ(got[0].discard.at, kReassemblyStart + 2ms);
  EXPECT_EQ(got[0].discard.first, kReassemblyStart);
  EXPECT_EQ(got[0].discard.last, kReassemblyStart + 1ms);
  EXPECT_EQ(rig.r.state(7, 2), State::resynchronising);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);  // no timer while resynchronising
  got = rig.feed({frames[3]});                     // the last fragment ends the broken packet
  EXPECT_TRUE(got.empty());
  EXPECT_EQ(rig.r.state(7, 2), State::idle);
  got = rig.feed(fragments(2, 7, counting(12, 0x50)));
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 7, 2, counting(12, 0x50));
  const auto& c = rig.r.counters();
  EXPECT_EQ(c.discarded(Reason::missing_fragment), 1u);
  EXPECT_EQ(c.discarded_fragments, 2u);
  EXPECT_EQ(c.discarded_bytes, 16u);
  EXPECT_EQ(c.dropped_frames, 2u);  // the offending frame and the last fragment
  EXPECT_EQ(c.packets, 1u);
  rig.expect_accounted();
}

TEST(PdopReassembler, ALostFirstFragmentIsAMissingFragmentWithNothingOpen) {
  ReassemblerRig rig;
  auto frames = fragments(1, 5, counting(30));  // 4 fragments
  auto got = rig.feed({frames[1]});             // t = 1 while idle
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::missing_fragment, 0);
  EXPECT_EQ(got[0].discard.first, kReassemblyStart);
  EXPECT_EQ(rig.r.state(5, 1), State::resynchronising);
  EXPECT_TRUE(rig.feed({frames[2], frames[3]}).empty());
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  // With c = 0 the offending frame is itself the end: idle at once.
  got = rig.feed({fragment_frame(1, 5, true, false, {1, 2})});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::missing_fragment, 0);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  rig.expect_accounted();
}

TEST(PdopReassembler, ALostLastFragmentAfterAnOddCountCostsTheNextPacketToo) {
  ReassemblerRig rig;
  auto two = fragments(1, 5, counting(16));  // 2 fragments
  two.pop_back();                            // 1 accepted: t = 1 expected next
  const auto next = fragments(1, 5, counting(20, 0x60));
  const auto after = fragments(1, 5, counting(5, 0x90));
  auto got = rig.feed({two[0], next[0]});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::missing_fragment, 1);
  // The offending frame is the next packet's first fragment: that packet is dropped whole.
  EXPECT_TRUE(rig.feed({next[1], next[2]}).empty());
  got = rig.feed(after);
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, counting(5, 0x90));
  EXPECT_EQ(rig.r.counters().dropped_frames, 3u);
  rig.expect_accounted();
}

TEST(PdopReassembler, ARepeatedFragmentIsADuplicate) {
  ReassemblerRig rig;
  const auto frames = fragments(3, 12, counting(30));  // 4 fragments
  auto got = rig.feed({frames[0], frames[1], frames[1]});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 12, 3, Reason::duplicate, 2);
  EXPECT_TRUE(rig.feed({frames[2], frames[3]}).empty());
  EXPECT_EQ(rig.r.state(12, 3), State::idle);
  // The first fragment twice: the repeat has t = 0 where 1 is expected.
  got = rig.feed({frames[0], frames[0], frames[1], frames[2], frames[3]});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 12, 3, Reason::duplicate, 1);
  EXPECT_EQ(rig.r.counters().discarded(Reason::duplicate), 2u);
  rig.expect_accounted();
}

TEST(PdopReassembler, ARepeatedLastFragmentWithToggle1IsReportedAndCostsNothing) {
  ReassemblerRig rig;
  const auto frames = fragments(1, 2, counting(16));  // 2 fragments: the last has t = 1
  auto got = rig.feed({frames[0], frames[1], frames[1]});
  ASSERT_EQ(got.size(), 2u);
  expect_packet(got[0], 2, 1, counting(16));
  expect_discard(got[1], 2, 1, Reason::duplicate, 0);
  EXPECT_EQ(rig.r.state(2, 1), State::idle);  // c = 0: nothing to drop
  got = rig.feed(fragments(1, 2, counting(3)));
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 2, 1, counting(3));
}

TEST(PdopReassembler, AToggleErrorThatRepeatsNoFragmentIsAMissingFragment) {
  ReassemblerRig rig;
  // Same toggle as the last accepted fragment, other bytes: a lost fragment in between.
  auto got = rig.feed({fragment_frame(1, 2, false, true, counting(8)),
                       fragment_frame(1, 2, false, true, counting(8, 1))});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 2, 1, Reason::missing_fragment, 1);
  // Same bytes, but c differs: not a repeat either.
  got = rig.feed({fragment_frame(1, 2, false, false, {1}),  // ends the resync
                  fragment_frame(1, 2, false, true, counting(8)),
                  fragment_frame(1, 2, false, false, counting(8))});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 2, 1, Reason::missing_fragment, 1);
  // t = 1 while idle after a packet that ended on t = 0: no repeat possible.
  got = rig.feed({fragment_frame(1, 2, false, false, {7}), fragment_frame(1, 2, true, false, {7})});
  ASSERT_EQ(got.size(), 2u);
  expect_discard(got[1], 2, 1, Reason::missing_fragment, 0);
}

TEST(PdopReassembler, TheTimerReportsATimeoutExactlyAtTheDeadline) {
  ReassemblerRig rig;
  const auto frames = fragments(4, 20, counting(24));  // 3 fragments
  rig.feed({frames[0], frames[1]}, kReassemblyStart,
           10ms);  // last accepted at kReassemblyStart + 10 ms
  ASSERT_EQ(rig.r.next_deadline(), kReassemblyStart + 110ms);
  EXPECT_TRUE(rig.tick(kReassemblyStart + 110ms - 1ns).empty());
  EXPECT_EQ(rig.r.state(20, 4), State::assembling);
  const auto got = rig.tick(kReassemblyStart + 110ms);
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 20, 4, Reason::timeout, 2);
  EXPECT_EQ(got[0].discard.first, kReassemblyStart);
  EXPECT_EQ(got[0].discard.last, kReassemblyStart + 10ms);
  EXPECT_EQ(got[0].discard.at, kReassemblyStart + 110ms);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);
  EXPECT_EQ(rig.r.state(20, 4), State::resynchronising);
  // The late last fragment is dropped and ends the broken packet.
  EXPECT_TRUE(rig.feed({frames[2]}, kReassemblyStart + 120ms).empty());
  EXPECT_EQ(rig.r.state(20, 4), State::idle);
  EXPECT_EQ(rig.r.counters().discarded(Reason::timeout), 1u);
  rig.expect_accounted();
}

TEST(PdopReassembler, AFragmentArrivingExactlyAtTheDeadlineIsLate) {
  ReassemblerRig rig;
  const auto frames = fragments(1, 3, counting(24));
  rig.feed({frames[0]}, kReassemblyStart);
  auto got = rig.feed({frames[1]}, kReassemblyStart + 100ms - 1ns);  // just in time
  EXPECT_TRUE(got.empty());
  got = rig.feed({frames[2]}, kReassemblyStart + 200ms - 2ns);  // the deadline moved with frames[1]
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 3, 1, counting(24));

  rig.feed({frames[0]}, kReassemblyStart + 1s);
  got = rig.feed({frames[1]},
                 kReassemblyStart + 1s + 100ms);  // exactly at the deadline, no tick before
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 3, 1, Reason::timeout, 1);
  EXPECT_EQ(got[0].discard.at, kReassemblyStart + 1s + 100ms);
  EXPECT_EQ(rig.r.state(3, 1), State::resynchronising);  // frames[1] has c = 1: dropped
  EXPECT_TRUE(rig.feed({frames[2]}, kReassemblyStart + 1s + 101ms).empty());
  EXPECT_EQ(rig.r.state(3, 1), State::idle);
}

TEST(PdopReassembler, NextDeadlineIsTheEarliestOfAllOpenPackets) {
  PdopReassemblerOptions o;
  o.fragment_timeout = 50ms;
  ReassemblerRig rig(o);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);
  rig.r.on_frame(fragments(1, 31, counting(16))[0], kReassemblyStart + 5ms, rig.sink);
  rig.r.on_frame(fragments(4, 1, counting(16))[0], kReassemblyStart + 3ms, rig.sink);
  rig.r.on_frame(fragments(2, 16, counting(16))[0], kReassemblyStart + 9ms, rig.sink);
  EXPECT_EQ(rig.r.next_deadline(), kReassemblyStart + 53ms);
  EXPECT_EQ(rig.r.assembling(), 3u);
  auto got = rig.tick(kReassemblyStart + 55ms);  // two are late, reported by node then TPDO
  ASSERT_EQ(got.size(), 2u);
  expect_discard(got[0], 1, 4, Reason::timeout, 1);
  expect_discard(got[1], 31, 1, Reason::timeout, 1);
  EXPECT_EQ(rig.r.next_deadline(), kReassemblyStart + 59ms);
  got = rig.tick(kReassemblyStart + 59ms);
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 16, 2, Reason::timeout, 1);
  EXPECT_EQ(rig.r.next_deadline(), std::nullopt);
  EXPECT_EQ(rig.r.assembling(), 0u);
}

TEST(PdopReassembler, GrowingPastMaxPacketBytesIsOversize) {
  PdopReassemblerOptions o;
  o.max_packet_bytes = 20;
  ReassemblerRig rig(o);
  auto got = rig.feed(fragments(1, 5, counting(20)));  // exactly the limit
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, counting(20));
  // 21 bytes: the last fragment (5 bytes) would grow 16 to 21; it has c = 0, so idle at once.
  got = rig.feed(fragments(1, 5, counting(21)));
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::oversize, 2);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  // 40 bytes: the third fragment (8 bytes, c = 1) is the offending one; resynchronise.
  const auto big = fragments(1, 5, counting(40));
  got = rig.feed({big[0], big[1], big[2]});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::oversize, 2);
  EXPECT_EQ(rig.r.state(5, 1), State::resynchronising);
  EXPECT_TRUE(rig.feed({big[3], big[4]}).empty());
  EXPECT_EQ(rig.r.counters().discarded(Reason::oversize), 2u);
  EXPECT_LE(rig.r.buffer_capacity(), 20u);
  rig.expect_accounted();
}

TEST(PdopReassembler, AOneByteLimitTakesOnlyOneBytePackets) {
  PdopReassemblerOptions o;
  o.max_packet_bytes = 1;
  ReassemblerRig rig(o);
  auto got = rig.feed({Frame::standard(0x185, {9}), Frame::standard(0x185, {9, 9})});
  ASSERT_EQ(got.size(), 2u);
  expect_packet(got[0], 5, 1, {9});
  expect_discard(got[1], 5, 1, Reason::oversize, 0);
  got = rig.feed(fragments(1, 5, counting(9)));  // the first fragment is already too big
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::oversize, 0);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);  // the second fragment had c = 0
}

TEST(PdopReassembler, ANonFinalFragmentShorterThan8BytesIsShort) {
  ReassemblerRig rig;
  auto got = rig.feed({fragment_frame(2, 4, false, true, counting(8)),
                       fragment_frame(2, 4, true, true, counting(7))});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 4, 2, Reason::short_fragment, 1);
  EXPECT_EQ(rig.r.state(4, 2), State::resynchronising);
  rig.feed({fragment_frame(2, 4, false, false, {1})});
  // Zero bytes with c = 1 is short too, also as a first fragment.
  got = rig.feed({fragment_frame(2, 4, false, true, {})});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 4, 2, Reason::short_fragment, 0);
  EXPECT_EQ(rig.r.counters().discarded(Reason::short_fragment), 2u);
}

TEST(PdopReassembler, AZeroLengthFrameWithC0IsAnEmptyFrame) {
  ReassemblerRig rig;
  auto got = rig.feed({Frame::standard(0x185, {})});  // a DLC 0 plain PDO: not a packet
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::empty_frame, 0);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  // Mid-packet, whatever its toggle: the partial packet goes, and it is the end mark.
  got = rig.feed({fragment_frame(1, 5, false, true, counting(8)), Frame::standard(0x1C5, {})});
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::empty_frame, 1);
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  // While resynchronising it is a c = 0 frame like any other: it ends the broken packet.
  rig.feed({fragment_frame(1, 5, true, true, counting(8)), Frame::standard(0x185, {})});
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  EXPECT_EQ(rig.r.counters().discarded(Reason::empty_frame), 2u);
  rig.expect_accounted();
}

TEST(PdopReassembler, ANodeRestartDiscardsItsOpenPacketsAndEndsResynchronisation) {
  ReassemblerRig rig;
  rig.feed({fragment_frame(1, 6, false, true, counting(8)),
            fragment_frame(3, 6, true, true, counting(8)),  // TPDO3: now resynchronising
            fragment_frame(2, 7, false, true, counting(8))});
  rig.sink.take();
  ASSERT_EQ(rig.r.state(6, 3), State::resynchronising);
  rig.r.on_node_restart(6, kReassemblyStart + 10ms, rig.sink);
  auto got = rig.sink.take();
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 6, 1, Reason::node_restart, 1);
  EXPECT_EQ(rig.r.state(6, 1), State::idle);
  EXPECT_EQ(rig.r.state(6, 3), State::idle);
  EXPECT_EQ(rig.r.state(7, 2), State::assembling);  // another node: untouched
  got = rig.feed(fragments(3, 6, counting(9)), kReassemblyStart + 20ms);
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 6, 3, counting(9));
  // Already past its deadline: that is a timeout, as the next fragment would have found.
  rig.r.on_node_restart(7, kReassemblyStart + 1s, rig.sink);
  got = rig.sink.take();
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 7, 2, Reason::timeout, 1);
  rig.r.on_node_restart(0, kReassemblyStart + 1s, rig.sink);   // out of range: nothing
  rig.r.on_node_restart(32, kReassemblyStart + 1s, rig.sink);  // out of range: nothing
  EXPECT_TRUE(rig.sink.got.empty());
}

TEST(PdopReassembler, LostFramesDiscardOpenPacketsAndResynchroniseEveryStream) {
  ReassemblerRig rig;
  // Node 6 TPDO1 has two fragments (t = 0, 1) open; node 7 TPDO2 is idle.
  rig.feed({fragment_frame(1, 6, false, true, counting(8)),
            fragment_frame(1, 6, true, true, counting(8))});
  ASSERT_EQ(rig.r.state(6, 1), State::assembling);
  rig.r.on_frames_lost(kReassemblyStart + 5ms, rig.sink);
  auto got = rig.sink.take();
  ASSERT_EQ(got.size(), 1u);  // only the open packet is reported
  expect_discard(got[0], 6, 1, Reason::frames_lost, 2);
  EXPECT_EQ(rig.r.state(6, 1), State::resynchronising);
  EXPECT_EQ(rig.r.state(7, 2), State::resynchronising);
  // Two fragments of node 6 were lost with the frames: what follows has t = 0 and would have
  // continued the open packet. It is dropped up to its c = 0 end.
  got = rig.feed({fragment_frame(1, 6, false, true, counting(8)),
                  fragment_frame(1, 6, true, false, counting(3))},
                 kReassemblyStart + 6ms);
  EXPECT_TRUE(got.empty());
  // The frame that carries the loss mark is a fragment like any other (it ends node 5's resync).
  Frame marked = fragment_frame(1, 5, true, false, counting(2));
  marked.flags |= can::FrameFlags::follows_loss;
  EXPECT_TRUE(rig.r.on_frame(marked, kReassemblyStart + 7ms, rig.sink));
  EXPECT_EQ(rig.r.state(5, 1), State::idle);
  // On node 7, an idle stream, the tail of a packet whose first two fragments were lost looks
  // like a packet of its own: it is not delivered.
  got = rig.feed({fragment_frame(2, 7, false, true, counting(8)),
                  fragment_frame(2, 7, true, false, counting(4))},
                 kReassemblyStart + 8ms);
  EXPECT_TRUE(got.empty());
  // After their ends, both streams deliver again.
  got = rig.feed(fragments(1, 6, counting(12)), kReassemblyStart + 10ms);
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 6, 1, counting(12));
  got = rig.feed(fragments(2, 7, counting(20)), kReassemblyStart + 20ms);
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 7, 2, counting(20));
  EXPECT_EQ(rig.r.counters().discarded(Reason::frames_lost), 1u);
  rig.expect_accounted();
}

TEST(PdopReassembler, AOneFramePacketRepeatingTheLastFragmentRightAfterIsFlagged) {
  ReassemblerRig rig;
  // 17 bytes: three fragments, the last one (1 byte) with t = 0: its double reception is a
  // valid one-frame packet.
  const auto frames = fragments(1, 4, counting(17));
  ASSERT_EQ(frames.size(), 3u);
  auto got = rig.feed(frames, kReassemblyStart, 100us);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_FALSE(got[0].probable_repeat);
  got = rig.feed({frames[2]},
                 kReassemblyStart + 300us);  // right after: flagged, delivered all the same
  ASSERT_EQ(got.size(), 1u);
  ASSERT_TRUE(got[0].packet);
  EXPECT_EQ(got[0].fragments, 1u);
  EXPECT_TRUE(got[0].probable_repeat);
  // The same bytes again: the packet before is one frame now, a plain TPDO repeating its value.
  got = rig.feed({frames[2]}, kReassemblyStart + 400us);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_FALSE(got[0].probable_repeat);
  // Later than kRepeatWindow after a multi-fragment packet: a packet of its own.
  rig.feed(frames, kReassemblyStart + 10ms, 100us);
  got =
      rig.feed({frames[2]}, kReassemblyStart + 10ms + 200us + PdopReassembler::kRepeatWindow + 1us);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_FALSE(got[0].probable_repeat);
  // Other bytes right after: not a repeat.
  rig.feed(frames, kReassemblyStart + 20ms, 100us);
  got =
      rig.feed({fragment_frame(1, 4, false, false, counting(2))}, kReassemblyStart + 20ms + 300us);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_FALSE(got[0].probable_repeat);
  EXPECT_EQ(rig.r.counters().probable_repeats, 1u);
}

TEST(PdopReassembler, DiscardsReadWellInTheLog) {
  PdopReassembler::Discard d;
  d.node = 5;
  d.tpdo = 2;
  d.reason = Reason::missing_fragment;
  d.fragments = 3;
  d.bytes = 24;
  EXPECT_EQ(to_string(d),
            "node 5 TPDO2: packet discarded (missing_fragment) after 3 fragments, "
            "24 bytes");
  d.fragments = 0;
  d.bytes = 0;
  d.reason = Reason::duplicate;
  EXPECT_EQ(to_string(d), "node 5 TPDO2: frame refused (duplicate) with no packet open");
  EXPECT_STREQ(to_string(Reason::empty_frame), "empty_frame");
  EXPECT_STREQ(to_string(Reason::node_restart), "node_restart");
  EXPECT_STREQ(to_string(Reason::frames_lost), "frames_lost");
}

// --- what one toggle bit cannot see (documented in the header) -----------------------------

TEST(PdopReassemblerLimits, TwoLostFragmentsInsideAPacketGoUnnoticed) {
  ReassemblerRig rig;
  auto frames = fragments(1, 5, counting(40));  // 5 fragments
  frames.erase(frames.begin() + 1, frames.begin() + 3);
  const auto got = rig.feed(frames);
  ASSERT_EQ(got.size(), 1u);
  ASSERT_TRUE(got[0].packet);
  EXPECT_EQ(got[0].data.size(), 24u);  // 16 bytes short, and nothing says so
}

TEST(PdopReassemblerLimits, TwoLostFirstFragmentsLeaveASuffixPacket) {
  ReassemblerRig rig;
  auto frames = fragments(1, 5, counting(40));
  frames.erase(frames.begin(), frames.begin() + 2);
  const auto got = rig.feed(frames);
  ASSERT_EQ(got.size(), 1u);
  expect_packet(got[0], 5, 1, counting(24, 16));
}

TEST(PdopReassemblerLimits, ALostLastFragmentAfterAnEvenCountMergesWithTheNextPacket) {
  ReassemblerRig rig;
  auto a = fragments(1, 5, counting(20));  // 3 fragments
  a.pop_back();                            // 2 accepted: t = 0 expected next
  const auto b = fragments(1, 5, counting(12, 0x40));
  auto both = a;
  both.insert(both.end(), b.begin(), b.end());
  auto got = rig.feed(both, kReassemblyStart, 10ms);  // b follows within fragment_timeout
  ASSERT_EQ(got.size(), 1u);
  ASSERT_TRUE(got[0].packet);
  EXPECT_EQ(got[0].data.size(), 28u);
  // A gap of fragment_timeout between the packets separates them: timeout, then b is dropped
  // as the offending frame and its continuation (it has c = 1).
  got = rig.feed(a, kReassemblyStart + 1s, 10ms);
  EXPECT_TRUE(got.empty());
  got = rig.feed(b, kReassemblyStart + 1s + 10ms + 100ms);
  ASSERT_EQ(got.size(), 1u);
  expect_discard(got[0], 5, 1, Reason::timeout, 2);
}

TEST(PdopReassemblerLimits, ARepeatedLastFragmentWithToggle0IsAOneFramePacket) {
  ReassemblerRig rig;
  const auto frames = fragments(1, 5, counting(20));  // the last (k = 2) has t = 0
  const auto got = rig.feed({frames[0], frames[1], frames[2], frames[2]});
  ASSERT_EQ(got.size(), 2u);
  expect_packet(got[0], 5, 1, counting(20));
  expect_packet(got[1], 5, 1, counting(4, 16));
}

TEST(PdopReassemblerLimits, AFragmentRepeatedAfterTheNextOneIsTakenIn) {
  ReassemblerRig rig;
  const auto frames = fragments(1, 5, counting(20));
  const auto got = rig.feed({frames[0], frames[1], frames[0], frames[1], frames[2]});
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].data.size(), 36u);
}

// --- memory ----------------------------------------------------------------------------------

TEST(PdopReassembler, SteadyTrafficAllocatesNothingOnceBuffersHaveGrown) {
  ReassemblerRig rig;
  const auto a = fragments(2, 9, counting(256));
  const auto b = fragments(1, 31, counting(100));
  const auto plain = Frame::standard(0x185, {1, 2});
  rig.feed(a);
  rig.feed(b);
  struct Counting : PdopReassembler::Sink {
    void on_packet(const PdopReassembler::Packet& p) override { bytes += p.data.size(); }
    void on_discard(const PdopReassembler::Discard&) override { ++discards; }
    std::size_t bytes = 0;
    int discards = 0;
  } sink;
#ifdef PDOP_REASSEMBLER_COUNTS_ALLOCATIONS
  static std::atomic<bool> counting_on{false};
  static std::atomic<int> allocations{0};
  static const int installed = __sanitizer_install_malloc_and_free_hooks(
      [](const volatile void*, std::size_t) {
        if (counting_on) ++allocations;
      },
      [](const volatile void*) {});
  ASSERT_NE(installed, 0);
  allocations = 0;
  counting_on = true;
#endif
  TimePoint at = kReassemblyStart + 1s;
  for (int i = 0; i < 50; ++i) {
    for (std::size_t k = 0; k < a.size(); ++k) {
      rig.r.on_frame(a[k], at, sink);
      if (k < b.size()) rig.r.on_frame(b[k], at, sink);
      rig.r.on_frame(plain, at, sink);
      at += 100us;
    }
    rig.r.tick(at, sink);
    (void)rig.r.next_deadline();
  }
#ifdef PDOP_REASSEMBLER_COUNTS_ALLOCATIONS
  counting_on = false;
  EXPECT_EQ(allocations, 0);
#endif
  EXPECT_EQ(sink.bytes, 50u * (256 + 100 + 2 * a.size()));
  EXPECT_EQ(sink.discards, 0);
}

// --- property test ---------------------------------------------------------------------------

// What a faulted packet is expected to produce, computed from the fault and the packet alone.
struct Expected {
  bool packet = false;
  Bytes data;       // packet
  Reason reason{};  // discard
  std::uint32_t fragments = 0;
};

enum class Fault {
  none,
  lose,         // fragment k (< n - 1), or fragments k..k+2
  repeat,       // fragment k (< n - 1) twice in a row
  repeat_last,  // the last fragment twice: t = 1 reported, t = 0 a one-frame ghost
  truncate,     // fragment k (< n - 1) shortened: short_fragment
  delay,        // a gap of fragment_timeout or more before fragment k (>= 1)
};

struct Plan {
  std::vector<Frame> frames;                          // what the bus carries, in order
  std::vector<std::chrono::microseconds> gap_before;  // extra silence before each frame
  std::vector<Expected> expected;                     // per stream, in order
};

struct Stats {
  std::size_t packets = 0, delivered = 0, discarded = 0, ghosts = 0, frames = 0;
  std::map<Fault, std::size_t> faults;
};

// One packet of `stream` with at most one fault from the set whose damage one toggle bit
// detects and contains (the last fragment always arrives).
void plan_packet(std::mt19937& rng, unsigned tpdo, unsigned node, std::size_t max,
                 std::chrono::milliseconds timeout, Plan& plan, Stats& stats) {
  const auto pick = [&](std::size_t lo, std::size_t hi) {
    return std::uniform_int_distribution<std::size_t>(lo, hi)(rng);
  };
  std::size_t size;
  const std::size_t shape = pick(0, 99);
  if (shape < 25) {
    size = pick(1, 8);  // plain PDOs
  } else if (shape < 30) {
    size = pick(max + 1, max + 40);  // oversize
  } else {
    size = pick(1, max);
  }
  // Random bytes, but every fragment starts with the packet's sequence number and its index,
  // so that no fragment repeats another one nearby by chance (which the reassembler would
  // rightly call a duplicate rather than a missing fragment).
  Bytes data(size);
  for (auto& b : data) b = static_cast<std::uint8_t>(rng());
  for (std::size_t j = 0; j < size; j += 8) {
    data[j] = static_cast<std::uint8_t>(stats.packets);
    if (j + 1 < size) data[j + 1] = static_cast<std::uint8_t>(j / 8);
  }
  const auto frames = fragments(tpdo, node, data);
  const std::size_t n = frames.size();
  ++stats.packets;

  Fault fault = Fault::none;
  const std::size_t roll = pick(0, 99);
  if (roll >= 55) {
    const Fault candidates[] = {Fault::lose, Fault::repeat, Fault::repeat_last, Fault::truncate,
                                Fault::delay};
    fault = candidates[pick(0, 4)];
    if (n < 2 && fault != Fault::repeat_last) fault = Fault::none;
    // A repeated last fragment of an oversize packet would start a packet of its own.
    if (size > max && fault == Fault::repeat_last) fault = Fault::none;
  }
  ++stats.faults[fault];

  // The oracle: how many fragments are accepted before `bad` (the index of the offending
  // frame, n for none) given oversize, and what is reported.
  const auto oversize_at = [&]() -> std::size_t {
    std::size_t bytes = 0;
    for (std::size_t k = 0; k < n; ++k) {
      if (bytes + frames[k].len > max) return k;
      bytes += frames[k].len;
    }
    return n;
  };
  const std::size_t over = oversize_at();
  std::size_t k = n >= 2 ? pick(0, n - 2) : 0;  // the faulted fragment
  std::size_t lost = fault == Fault::lose ? (k + 3 <= n - 1 && pick(0, 1) ? 3 : 1) : 0;
  if (fault == Fault::delay && n >= 2) k = pick(1, n - 1);
  // Fragment k's fault only shows if the packet is not already oversize before it.
  const std::size_t bad = fault == Fault::none || fault == Fault::repeat_last ? n
                          : fault == Fault::repeat                            ? k + 1
                                                                              : k;
  std::vector<std::pair<Frame, std::chrono::microseconds>> out;
  for (std::size_t j = 0; j < n; ++j) {
    if (fault == Fault::lose && j >= k && j < k + lost) continue;
    std::chrono::microseconds gap{0};
    if (fault == Fault::delay && j == k) gap = timeout + std::chrono::microseconds(pick(0, 5000));
    Frame f = frames[j];
    if (fault == Fault::truncate && j == k) f.len = static_cast<std::uint8_t>(pick(0, 7));
    out.emplace_back(f, gap);
    if ((fault == Fault::repeat && j == k) || (fault == Fault::repeat_last && j == n - 1)) {
      out.emplace_back(frames[j], std::chrono::microseconds{0});
    }
  }
  for (auto& [f, gap] : out) {
    plan.frames.push_back(f);
    plan.gap_before.push_back(gap);
  }

  Expected e;
  if (over < bad) {
    e.reason = Reason::oversize;
    e.fragments = static_cast<std::uint32_t>(over);
  } else if (bad < n) {
    e.fragments = static_cast<std::uint32_t>(bad);
    switch (fault) {
      case Fault::lose:
        e.reason = Reason::missing_fragment;
        break;
      case Fault::repeat:
        e.reason = Reason::duplicate;
        break;
      case Fault::truncate:
        e.reason = Reason::short_fragment;
        break;
      case Fault::delay:
        e.reason = Reason::timeout;
        break;
      default:
        FAIL();
    }
  } else {
    e.packet = true;
    e.data = data;
  }
  plan.expected.push_back(e);
  if (fault == Fault::repeat_last && e.packet) {
    Expected again;
    if (n % 2 == 0) {  // the last fragment has t = 1: refused while idle, nothing open
      again.reason = Reason::duplicate;
    } else {  // t = 0, c = 0: a valid one-frame packet of the last fragment's bytes
      again.packet = true;
      again.data.assign(data.begin() + static_cast<std::ptrdiff_t>(8 * (n - 1)), data.end());
      ++stats.ghosts;
    }
    plan.expected.push_back(again);
  }
}

struct Stream {
  unsigned node;
  unsigned tpdo;
  Plan plan;
  std::size_t next = 0;
  TimePoint ready{};  // not before (a delay fault)
};

void run_property(std::uint32_t seed, bool timer, Stats& stats) {
  SCOPED_TRACE("seed " + std::to_string(seed) + (timer ? " with timer" : " without timer"));
  std::mt19937 rng(seed);
  PdopReassemblerOptions o;
  o.max_packet_bytes = 64 + rng() % 449;  // 64..512
  o.fragment_timeout = 100ms;
  PdopReassembler r(o);
  Recorder sink;

  // 10 streams of nodes 1..31 (1 and 31 always) and TPDOs 1..4.
  std::vector<Stream> streams;
  std::vector<std::pair<unsigned, unsigned>> keys{{1, 1}, {31, 4}};
  while (keys.size() < 10) {
    const std::pair<unsigned, unsigned> k{1 + rng() % 31, 1 + rng() % 4};
    if (std::find(keys.begin(), keys.end(), k) == keys.end()) keys.push_back(k);
  }
  for (const auto& [node, tpdo] : keys) {
    Stream s{node, tpdo, {}};
    for (int i = 0; i < 200; ++i) {
      plan_packet(rng, tpdo, node, o.max_packet_bytes, o.fragment_timeout, s.plan, stats);
    }
    streams.push_back(std::move(s));
  }

  TimePoint now = kReassemblyStart;
  for (;;) {
    std::vector<std::size_t> ready;
    std::optional<TimePoint> soonest;
    for (std::size_t i = 0; i < streams.size(); ++i) {
      Stream& s = streams[i];
      if (s.next == s.plan.frames.size()) continue;
      if (s.ready == TimePoint{}) s.ready = now + s.plan.gap_before[s.next];
      if (s.ready <= now) {
        ready.push_back(i);
      } else if (!soonest || s.ready < *soonest) {
        soonest = s.ready;
      }
    }
    if (ready.empty()) {
      if (!soonest) break;
      now = *soonest;
      continue;
    }
    Stream& s = streams[ready[rng() % ready.size()]];
    if (timer) {
      while (const auto deadline = r.next_deadline()) {
        if (*deadline > now) break;
        r.tick(*deadline, sink);
        ASSERT_NE(r.next_deadline(), deadline) << "tick() at next_deadline() did nothing";
      }
    }
    ASSERT_TRUE(r.on_frame(s.plan.frames[s.next], now, sink));
    ++stats.frames;
    ++s.next;
    s.ready = TimePoint{};
    now += std::chrono::microseconds(rng() % 200);  // far below fragment_timeout
    if (stats.frames % 64 == 0) {
      ASSERT_LE(r.buffer_capacity(), PdopReassembler::kStreamCount * o.max_packet_bytes);
      ASSERT_LE(r.assembling(), streams.size());
    }
  }
  r.tick(now + 1s, sink);

  for (const Stream& s : streams) {
    SCOPED_TRACE("node " + std::to_string(s.node) + " TPDO" + std::to_string(s.tpdo));
    std::vector<const Got*> got;
    for (const Got& g : sink.got) {
      if (g.node == s.node && g.tpdo == s.tpdo) got.push_back(&g);
    }
    ASSERT_EQ(got.size(), s.plan.expected.size());
    for (std::size_t i = 0; i < got.size(); ++i) {
      const Expected& e = s.plan.expected[i];
      const Got& g = *got[i];
      SCOPED_TRACE("result " + std::to_string(i));
      ASSERT_EQ(g.packet, e.packet) << g;
      if (e.packet) {
        ASSERT_EQ(g.data, e.data);  // bit-exact
        ++stats.delivered;
      } else {
        ASSERT_EQ(g.discard.reason, e.reason) << g;
        ASSERT_EQ(g.discard.fragments, e.fragments) << g;
        ++stats.discarded;
      }
    }
    EXPECT_EQ(r.state(static_cast<canopen::NodeId>(s.node), s.tpdo), State::idle);
  }
  EXPECT_EQ(r.assembling(), 0u);
  const auto& c = r.counters();
  EXPECT_EQ(c.frames, c.packet_fragments + c.discarded_fragments + c.dropped_frames);
}

TEST(PdopReassemblerProperty, EveryIntactPacketOnceAndBitExactEveryBrokenOneReported) {
  Stats stats;
  for (std::uint32_t seed : {1u, 2u, 3u, 0xC0FFEEu, 20240611u, 77u}) {
    for (bool timer : {true, false}) {
      run_property(seed, timer, stats);
      if (HasFatalFailure()) return;
    }
  }
  // The run covered what it claims to: thousands of packets, every fault, both outcomes.
  EXPECT_GE(stats.packets, 24000u);
  for (Fault f : {Fault::none, Fault::lose, Fault::repeat, Fault::repeat_last, Fault::truncate,
                  Fault::delay}) {
    EXPECT_GT(stats.faults[f], 300u);
  }
  EXPECT_GT(stats.delivered, 12000u);
  EXPECT_GT(stats.discarded, 4000u);
  EXPECT_GT(stats.ghosts, 50u);
  std::printf("[ property ] %zu packets, %zu frames: %zu delivered, %zu discarded, %zu ghosts\n",
              stats.packets, stats.frames, stats.delivered, stats.discarded, stats.ghosts);
}

// The fuzz target's reference model and invariants on seeded random inputs, shaped like the
// target's input (two option bytes, then 4-byte operations) with mostly whole packets.
TEST(PdopReassemblerFuzz, RandomInputsMatchTheReferenceModel) {
  for (std::uint32_t seed = 1; seed <= 1500; ++seed) {
    std::mt19937 rng(seed);
    std::vector<std::uint8_t> input(2 + 4 * (1 + rng() % 64));
    for (auto& b : input) b = static_cast<std::uint8_t>(rng());
    for (std::size_t i = 2; i + 4 <= input.size(); i += 4) {
      if (rng() % 3 == 0) {  // a whole packet of at most 128 bytes
        input[i] = static_cast<std::uint8_t>(0x80 | (input[i] & 0x3F));
        input[i + 1] &= 0x3F;
      }
      if (rng() % 2 == 0) input[i + 3] &= 0x07;  // mostly short steps
    }
    LLVMFuzzerTestOneInput(input.data(), input.size());  // aborts on a violated invariant
  }
}

}  // namespace
}  // namespace canbridge::bridge
