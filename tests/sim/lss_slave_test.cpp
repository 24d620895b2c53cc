// The simulated LSS slave on its own: which services need the configuration state, how switch
// selective matches, and what configure / store answer.
#include "sim/lss_slave.hpp"

#include <gtest/gtest.h>

#include <vector>

namespace canbridge::sim {
namespace {

using can::Frame;
using Frames = std::vector<Frame>;

Frame request(std::uint8_t command, std::uint32_t value = 0) {
  return Frame::standard(
      0x7E5,
      {command, static_cast<std::uint8_t>(value), static_cast<std::uint8_t>(value >> 8),
       static_cast<std::uint8_t>(value >> 16), static_cast<std::uint8_t>(value >> 24), 0, 0, 0});
}

Frame answer(std::uint8_t command, std::uint32_t value = 0) {
  Frame f = request(command, value);
  f.id = 0x7E4;
  return f;
}

LssSlaveOptions options() {
  LssSlaveOptions o;
  o.address = {0x11, 0x22, 0x33, 0x44};
  o.active_node_id = 7;
  return o;
}

Frames feed(LssSlave& slave, const Frames& frames) {
  Frames out;
  for (const auto& f : frames) slave.on_frame(f, out);
  return out;
}

TEST(LssSlave, WaitingStateAnswersOnlyTheSelection) {
  LssSlave slave(options());
  EXPECT_TRUE(feed(slave, {request(0x5E), request(0x5A), request(0x11, 9), request(0x17)}).empty());
  EXPECT_FALSE(slave.pending_node_id());
  EXPECT_FALSE(slave.stored_node_id());
}

TEST(LssSlave, SelectiveNeedsAllFourPartsInOrder) {
  LssSlave slave(options());
  // Wrong product: the rest of this sequence is ignored.
  EXPECT_TRUE(feed(slave, {request(0x40, 0x11), request(0x41, 0x99), request(0x42, 0x33),
                           request(0x43, 0x44)})
                  .empty());
  // Out of order.
  EXPECT_TRUE(feed(slave, {request(0x40, 0x11), request(0x42, 0x33), request(0x43, 0x44)}).empty());
  EXPECT_FALSE(slave.in_configuration());
  // A new vendor part restarts the selection.
  EXPECT_EQ(feed(slave, {request(0x40, 0x11), request(0x41, 0x22), request(0x40, 0x11),
                         request(0x41, 0x22), request(0x42, 0x33), request(0x43, 0x44)}),
            Frames{answer(0x44)});
  EXPECT_TRUE(slave.in_configuration());
}

TEST(LssSlave, ConfigurationStateServices) {
  LssSlave slave(options());
  feed(slave, {request(0x04, 1)});
  ASSERT_TRUE(slave.in_configuration());
  EXPECT_EQ(
      feed(slave, {request(0x5A), request(0x5B), request(0x5C), request(0x5D), request(0x5E)}),
      (Frames{answer(0x5A, 0x11), answer(0x5B, 0x22), answer(0x5C, 0x33), answer(0x5D, 0x44),
              answer(0x5E, 7)}));
  EXPECT_EQ(feed(slave, {request(0x11, 0)}), Frames{answer(0x11, 1)});  // out of range
  EXPECT_EQ(feed(slave, {request(0x11, 128)}), Frames{answer(0x11, 1)});
  EXPECT_FALSE(slave.pending_node_id());
  EXPECT_EQ(feed(slave, {request(0x11, 9)}), Frames{answer(0x11, 0)});
  EXPECT_EQ(slave.pending_node_id(), 9);
  EXPECT_EQ(feed(slave, {request(0x13)}), Frames{answer(0x13, 1)});  // bit timing: not supported
  EXPECT_EQ(feed(slave, {request(0x17)}), Frames{answer(0x17, 0)});
  EXPECT_EQ(slave.stored_node_id(), 9);
  // The active id answers until a reset applies the new one.
  EXPECT_EQ(feed(slave, {request(0x5E)}), Frames{answer(0x5E, 7)});
  slave.set_active_node_id(9);
  EXPECT_FALSE(slave.pending_node_id());
  feed(slave, {request(0x04, 0)});
  EXPECT_FALSE(slave.in_configuration());
}

TEST(LssSlave, StoreWithoutMemoryIsNotSupported) {
  auto o = options();
  o.store_supported = false;
  LssSlave slave(o);
  feed(slave, {request(0x04, 1)});
  EXPECT_EQ(feed(slave, {request(0x17)}), Frames{answer(0x17, 1)});
  EXPECT_FALSE(slave.stored_node_id());
}

TEST(LssSlave, IgnoresShortFramesAndOtherIds) {
  LssSlave slave(options());
  Frames out;
  slave.on_frame(Frame::standard(0x7E5, {0x04, 0x01}), out);  // CiA 305 frames have 8 bytes
  slave.on_frame(Frame::standard(0x7E4, {0x04, 0x01, 0, 0, 0, 0, 0, 0}), out);
  EXPECT_TRUE(out.empty());
  EXPECT_FALSE(slave.in_configuration());
}

}  // namespace
}  // namespace canbridge::sim
