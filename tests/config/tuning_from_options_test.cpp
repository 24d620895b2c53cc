// make_tuning: what the backbone gets from a role's session settings, the derived write bound.
#include "app/tuning_from_options.hpp"

#include <gtest/gtest.h>

namespace canbridge::bridge {
namespace {

TEST(TuningFromOptions, TcpWritesStayLargeWhenTheConfigLeavesTheBoundToTheLink) {
  const BackboneTuning tuning = make_tuning(config::SessionTuning{});
  EXPECT_EQ(tuning.session.max_write_bytes, 16384u);
  EXPECT_EQ(tuning.outbox.max_batch_bytes, 4096u);
}

TEST(TuningFromOptions, ASerialLineWritesAboutFiftyMillisecondsOfLineTime) {
  // 115200 bit/s, 8N1: 11,520 bytes/s, so 576 bytes per write and per batch.
  BackboneTuning tuning = make_tuning(config::SessionTuning{}, 11'520);
  EXPECT_EQ(tuning.session.max_write_bytes, 576u);
  EXPECT_EQ(tuning.outbox.max_batch_bytes, 576u);
  // 1 Mbit/s: 5,000 bytes per write; batches keep their own 4096-byte bound.
  tuning = make_tuning(config::SessionTuning{}, 100'000);
  EXPECT_EQ(tuning.session.max_write_bytes, 5000u);
  EXPECT_EQ(tuning.outbox.max_batch_bytes, 4096u);
  // A very slow line still writes whole messages' worth (floor 256).
  EXPECT_EQ(make_tuning(config::SessionTuning{}, 960).session.max_write_bytes, 256u);
}

TEST(TuningFromOptions, AnExplicitWriteBoundWinsOverTheDerivedOne) {
  config::SessionTuning configured;
  configured.max_write_bytes = 512;
  EXPECT_EQ(make_tuning(configured, 11'520).session.max_write_bytes, 512u);
  EXPECT_EQ(make_tuning(configured).session.max_write_bytes, 512u);
}

}  // namespace
}  // namespace canbridge::bridge
