// FirmwareDownload against a simulated qd node (seeds/003 loader) on a simulated clock: the whole
// update, refused images, missing boot-ups, long erase pauses, cancel and rerun.
#include "canopen/firmware_download.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

#include "canopen/sdo_abort.hpp"
#include "sim/firmware_image.hpp"
#include "sim/sim_node.hpp"

namespace canbridge::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using Frames = std::vector<Frame>;
using TimePoint = FirmwareDownload::TimePoint;

const TimePoint t0 = TimePoint{} + 1h;

sim::NodeSpec qd_spec(NodeId id) {
  sim::NodeSpec c;
  c.kind = sim::NodeKind::qd;
  c.node_id = id;
  c.identity = {0x0000AA55, 0x00000300, 0x00010000, 0x00004711};
  c.heartbeat_ms = 500;
  return c;
}

std::vector<std::uint8_t> program(std::size_t size, std::uint8_t seed) {
  std::vector<std::uint8_t> bytes(size);
  for (std::size_t i = 0; i < size; ++i) bytes[i] = static_cast<std::uint8_t>(i * 31 + seed);
  return bytes;
}

bool is_from(const Frame& f, std::uint32_t id) {
  return f.id == id;
}

// The bus between one sequencer and one simulated node, on a simulated clock. `filter` sees
// every frame the node sends and says when the sequencer gets it: `now` (passes), later (a
// pause such as a flash erase), or TimePoint::max() (lost).
struct Rig {
  explicit Rig(sim::NodeSpec spec) : node(spec) { node.boot(now); }

  std::function<TimePoint(const Frame&, TimePoint now)> filter;
  sim::SimNode node;
  TimePoint now = t0;
  struct Held {
    TimePoint due;
    Frame frame;
  };
  std::vector<Held> held;                  // node -> sequencer, delayed
  Frames sent;                             // everything the sequencer sent
  std::vector<FirmwareProgress> progress;  // at every step change

  void deliver_to_node(const Frames& frames) {
    for (const auto& f : frames) {
      sent.push_back(f);
      from_node(node.on_frame(f, now));
    }
  }
  void from_node(const Frames& frames) {
    for (const auto& f : frames) {
      const TimePoint due = filter ? filter(f, now) : now;
      if (due != TimePoint::max()) held.push_back({due, f});
    }
  }
  void note(const FirmwareDownload& d) {
    const auto p = d.progress();
    if (progress.empty() || progress.back().step != p.step) progress.push_back(p);
  }

  // Runs until the sequencer finishes (or a safety limit of simulated time).
  FirmwareResult run(FirmwareDownload& d) {
    Frames out;
    d.start(now, out);
    note(d);
    deliver_to_node(std::exchange(out, {}));
    while (!d.finished() && now < t0 + 10min) {
      // Frames due now first, in order; then the earliest of: a held frame, the node's timer,
      // the sequencer's deadline.
      auto due =
          std::find_if(held.begin(), held.end(), [&](const Held& h) { return h.due <= now; });
      if (due != held.end()) {
        const Frame f = due->frame;
        held.erase(due);
        d.on_frame(f, now, out);
        note(d);
        deliver_to_node(std::exchange(out, {}));
        continue;
      }
      TimePoint next = std::min(d.deadline(), node.next_deadline());
      for (const auto& h : held) next = std::min(next, h.due);
      if (next == TimePoint::max()) break;
      now = std::max(now, next);
      from_node(node.on_tick(now));
      if (now >= d.deadline()) {
        d.on_timeout(now, out);
        note(d);
        deliver_to_node(std::exchange(out, {}));
      }
    }
    EXPECT_TRUE(d.finished());
    return d.finished() ? d.result() : FirmwareResult{};
  }

  std::uint32_t read_u32(std::uint16_t index, std::uint8_t sub) {
    const Frames answer =
        node.on_frame(Frame::standard(0x600 + node.id(),
                                      {0x40, static_cast<std::uint8_t>(index),
                                       static_cast<std::uint8_t>(index >> 8), sub, 0, 0, 0, 0}),
                      now);
    EXPECT_EQ(answer.size(), 1u);
    if (answer.empty() || answer[0].data[0] == 0x80) return 0xFFFFFFFF;
    return static_cast<std::uint32_t>(answer[0].data[4] | answer[0].data[5] << 8 |
                                      answer[0].data[6] << 16 | answer[0].data[7] << 24);
  }
};

FirmwareDownloadOptions options() {
  FirmwareDownloadOptions o;
  o.answer_timeout = 2s;
  o.boot_timeout = 3s;
  o.block_size = 127;
  return o;
}

std::vector<FirmwareStep> steps(const std::vector<FirmwareProgress>& progress) {
  std::vector<FirmwareStep> s;
  for (const auto& p : progress) s.push_back(p.step);
  return s;
}

TEST(FirmwareDownload, Flashes256KiBImageFromTheRunningApplication) {
  Rig rig(qd_spec(5));
  ASSERT_FALSE(rig.node.in_loader());
  const auto application = program(256 * 1024 - 4, 3);
  const auto image = sim::firmware::make_image(application);
  ASSERT_EQ(image.size(), 256u * 1024);
  FirmwareDownload d(5, image, options());
  EXPECT_EQ(d.expected_identification(), sim::firmware::crc32(application));

  const auto result = rig.run(d);
  EXPECT_TRUE(result.ok()) << result.error.message() << ": " << result.detail;
  EXPECT_EQ(result.step, FirmwareStep::done);
  EXPECT_EQ(
      steps(rig.progress),
      (std::vector<FirmwareStep>{FirmwareStep::probe, FirmwareStep::stop, FirmwareStep::wait_loader,
                                 FirmwareStep::download, FirmwareStep::verify, FirmwareStep::start,
                                 FirmwareStep::wait_application, FirmwareStep::done}));
  EXPECT_EQ(d.progress().bytes_done, image.size());
  EXPECT_EQ(d.progress().bytes_total, image.size());
  EXPECT_FALSE(rig.node.in_loader());
  EXPECT_EQ(rig.node.counters().images_accepted, 1u);
  // The running application now reports the new program.
  EXPECT_EQ(rig.read_u32(0x1F56, 1), sim::firmware::crc32(application));
  // Block transfer, not segmented: 7 bytes per segment in sub-blocks of 127.
  const auto full_blocks = std::count_if(rig.sent.begin(), rig.sent.end(), [](const Frame& f) {
    return f.id == 0x605 && f.data[0] == 127;  // last segment of a full sub-block
  });
  EXPECT_EQ(full_blocks, static_cast<long>(image.size() / (127 * 7)));
}

TEST(FirmwareDownload, CallerSaysLoaderSoNeitherProbeNorStop) {
  auto spec = qd_spec(6);
  spec.loader.wait_for_command = true;
  Rig rig(spec);
  ASSERT_TRUE(rig.node.in_loader());
  const auto image = sim::firmware::make_image(program(1000, 9));
  FirmwareDownload d(6, image, options(), FirmwareStartMode::loader);
  EXPECT_TRUE(rig.run(d).ok());
  // The first request is the block download initiate of 1F50h:01.
  ASSERT_FALSE(rig.sent.empty());
  EXPECT_EQ(rig.sent[0].id, 0x606u);
  EXPECT_EQ(rig.sent[0].data[0] & 0xE0, 0xC0);
  EXPECT_EQ(rig.sent[0].data[1], 0x50);
  EXPECT_EQ(steps(rig.progress).front(), FirmwareStep::download);
}

TEST(FirmwareDownload, CorruptImageIsRefusedAtVerifyAndTheNodeStaysInItsLoader) {
  Rig rig(qd_spec(7));
  const auto application = program(4000, 1);
  auto image = sim::firmware::make_image(application);
  image[1234] ^= 0x10;  // damaged on its way: the trailer no longer matches
  FirmwareDownload bad(7, image, options());
  const auto result = rig.run(bad);
  EXPECT_EQ(result.error, SdoAbort::cannot_transfer);
  EXPECT_EQ(result.step, FirmwareStep::verify);
  EXPECT_NE(result.detail.find("1F56h:01 is 0x00000000"), std::string::npos) << result.detail;
  EXPECT_TRUE(rig.node.in_loader());
  EXPECT_EQ(rig.node.counters().images_rejected, 1u);
  // No start was sent: the last request is the read of 1F56h:01.
  EXPECT_EQ(rig.sent.back().data[0], 0x40);
  EXPECT_EQ(rig.sent.back().data[1], 0x56);

  // Running it again with the good image: the probe finds the loader and the update completes.
  rig.sent.clear();
  rig.progress.clear();
  FirmwareDownload good(7, sim::firmware::make_image(application), options());
  const auto rerun = rig.run(good);
  EXPECT_TRUE(rerun.ok()) << rerun.detail;
  EXPECT_EQ(steps(rig.progress),
            (std::vector<FirmwareStep>{FirmwareStep::probe, FirmwareStep::download,
                                       FirmwareStep::verify, FirmwareStep::start,
                                       FirmwareStep::wait_application, FirmwareStep::done}));
  EXPECT_FALSE(rig.node.in_loader());
  EXPECT_EQ(rig.read_u32(0x1F56, 1), sim::firmware::crc32(application));
}

TEST(FirmwareDownload, NoLoaderBootUpTimesOutAtWaitLoader) {
  Rig rig(qd_spec(8));
  // The node takes the stop command but its loader never announces itself.
  rig.filter = [](const Frame& f, TimePoint now) {
    return is_from(f, 0x728) ? TimePoint::max() : now;
  };
  auto o = options();
  o.boot_timeout = 4s;
  FirmwareDownload d(8, sim::firmware::make_image(program(100, 2)), o);
  const auto result = rig.run(d);
  EXPECT_EQ(result.error, SdoAbort::cannot_transfer);
  EXPECT_EQ(result.step, FirmwareStep::wait_loader);
  EXPECT_NE(result.detail.find("0x728"), std::string::npos) << result.detail;
  // Nothing was downloaded.
  EXPECT_EQ(rig.node.counters().images_accepted + rig.node.counters().images_rejected, 0u);
}

TEST(FirmwareDownload, NoApplicationBootUpTimesOutAtWaitApplication) {
  Rig rig(qd_spec(9));
  rig.filter = [](const Frame& f, TimePoint now) {
    return is_from(f, 0x709) ? TimePoint::max() : now;
  };
  FirmwareDownload d(9, sim::firmware::make_image(program(100, 2)), options());
  const TimePoint began = rig.now;
  const auto result = rig.run(d);
  EXPECT_EQ(result.error, SdoAbort::cannot_transfer);
  EXPECT_EQ(result.step, FirmwareStep::wait_application);
  EXPECT_EQ(rig.now - began, options().boot_timeout);
}

TEST(FirmwareDownload, LoaderThatResetsWithoutAnsweringStopIsAccepted) {
  Rig rig(qd_spec(10));
  // The answer to 1F51h:01 = 0 is lost: the loader's boot-up is the answer.
  rig.filter = [](const Frame& f, TimePoint now) {
    return f.id == 0x58A && f.data[0] == 0x60 && f.data[1] == 0x51 ? TimePoint::max() : now;
  };
  FirmwareDownload d(10, sim::firmware::make_image(program(100, 2)), options());
  EXPECT_TRUE(rig.run(d).ok());
  EXPECT_EQ(rig.now, t0);  // no timeout was waited out
}

// A loader erasing flash is silent for seconds before it confirms a sub-block (the `at`th).
TimePoint erase_pause(const Frame& f, TimePoint now, std::chrono::milliseconds pause, int at,
                      int& acks) {
  const bool block_ack = (f.id & 0x780) == 0x580 && f.data[0] == 0xA2;
  if (block_ack && ++acks == at) return now + pause;
  return now;
}

TEST(FirmwareDownload, LongErasePauseWithinTheAnswerTimeoutIsTolerated) {
  auto spec = qd_spec(11);
  spec.sdo_timeout = 30s;  // the pause is the loader's own: its SDO server does not give up
  Rig rig(spec);
  int acks = 0;
  rig.filter = [&](const Frame& f, TimePoint now) { return erase_pause(f, now, 8s, 1, acks); };
  auto o = options();
  o.answer_timeout = 10s;
  FirmwareDownload d(11, sim::firmware::make_image(program(20000, 4)), o);
  const auto result = rig.run(d);
  EXPECT_TRUE(result.ok()) << result.detail;
  EXPECT_GT(acks, 1);
  EXPECT_GE(rig.now - t0, 8s);
}

TEST(FirmwareDownload, ErasePauseBeyondTheAnswerTimeoutFailsTheDownloadAndARerunSucceeds) {
  auto spec = qd_spec(12);
  spec.sdo_timeout = 30s;  // the loader's side waits longer than the master's
  Rig rig(spec);
  int acks = 0;
  rig.filter = [&](const Frame& f, TimePoint now) { return erase_pause(f, now, 8s, 2, acks); };
  const auto image = sim::firmware::make_image(program(20000, 4));
  FirmwareDownload d(12, image, options());  // 2 s per answer
  const auto result = rig.run(d);
  EXPECT_EQ(result.error, SdoAbort::timeout);
  EXPECT_EQ(result.step, FirmwareStep::download);
  EXPECT_EQ(d.progress().bytes_done, 127u * 7);  // the first sub-block was confirmed
  EXPECT_LT(d.progress().bytes_done, image.size());
  // The master told the node it gave up.
  ASSERT_FALSE(rig.sent.empty());
  EXPECT_EQ(rig.sent.back().data[0], 0x80);
  EXPECT_TRUE(rig.node.in_loader());

  rig.now += 9s;  // the late answer passes by, unclaimed
  rig.held.clear();
  rig.filter = nullptr;
  FirmwareDownload again(12, image, options());
  EXPECT_TRUE(rig.run(again).ok());
  EXPECT_FALSE(rig.node.in_loader());
}

TEST(FirmwareDownload, CancelDuringTheDownloadAbortsTheTransferAndNamesTheStep) {
  Rig rig(qd_spec(13));
  FirmwareDownload d(13, sim::firmware::make_image(program(50000, 5)), options());
  Frames out;
  d.start(rig.now, out);
  rig.deliver_to_node(std::exchange(out, {}));
  // Feed answers until the download is under way.
  while (d.progress().step != FirmwareStep::download || d.progress().bytes_done == 0) {
    ASSERT_FALSE(rig.held.empty());
    const Frame f = rig.held.front().frame;
    rig.held.erase(rig.held.begin());
    d.on_frame(f, rig.now, out);
    rig.deliver_to_node(std::exchange(out, {}));
    ASSERT_FALSE(d.finished());
  }
  d.abort(SdoAbort::local_control, out);
  ASSERT_TRUE(d.finished());
  EXPECT_EQ(d.progress().bytes_done, 127u * 7);  // what the node confirmed before the cancel
  EXPECT_EQ(d.result().error, SdoAbort::local_control);
  EXPECT_EQ(d.result().step, FirmwareStep::download);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].id, 0x60Du);
  EXPECT_EQ(out[0].data[0], 0x80);
  EXPECT_EQ(d.deadline(), TimePoint::max());
  out.clear();
  d.abort(SdoAbort::local_control, out);  // once finished: nothing
  EXPECT_TRUE(out.empty());
}

TEST(FirmwareDownload, ImageWithoutProgramFailsAtOnce) {
  Rig rig(qd_spec(14));
  FirmwareDownload d(14, {1, 2, 3, 4}, options());
  Frames out;
  d.start(rig.now, out);
  ASSERT_TRUE(d.finished());
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(d.result().error, SdoAbort::cannot_transfer);
  EXPECT_EQ(d.result().step, FirmwareStep::download);
}

TEST(FirmwareDownload, NodeWithoutLoaderObjectsFailsAtStop) {
  sim::NodeSpec spec;
  spec.kind = sim::NodeKind::cia301;
  spec.node_id = 15;
  Rig rig(spec);
  FirmwareDownload d(15, sim::firmware::make_image(program(100, 2)), options());
  const auto result = rig.run(d);
  EXPECT_EQ(result.error, SdoAbort::no_object);
  EXPECT_EQ(result.step, FirmwareStep::stop);
  EXPECT_NE(result.detail.find("1F51h:01"), std::string::npos);
}

TEST(FirmwareDownload, RejectsBadNodeAndBlockSize) {
  EXPECT_THROW(FirmwareDownload(0, {1, 2, 3, 4, 5}, options()), std::invalid_argument);
  EXPECT_THROW(FirmwareDownload(128, {1, 2, 3, 4, 5}, options()), std::invalid_argument);
  auto o = options();
  o.block_size = 128;
  EXPECT_THROW(FirmwareDownload(1, {1, 2, 3, 4, 5}, o), std::invalid_argument);
}

TEST(FirmwareDownload, StepNames) {
  EXPECT_STREQ(to_string(FirmwareStep::wait_loader), "wait_loader");
  EXPECT_STREQ(to_string(FirmwareStep::wait_application), "wait_application");
  EXPECT_STREQ(to_string(FirmwareStep::verify), "verify");
}

}  // namespace
}  // namespace canbridge::canopen
