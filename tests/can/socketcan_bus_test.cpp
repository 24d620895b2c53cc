// Host-side checks of SocketCanBus: what does not need a CAN interface. The behaviour on real
// vcan interfaces is proven in tests/can_system (run in the vcan rig).
#include "can/socketcan_bus.hpp"

#include <gtest/gtest.h>

#include <boost/asio/io_context.hpp>

namespace canbridge::can {
namespace {

namespace asio = boost::asio;

TEST(SocketCanBus, RefusesInvalidOptions) {
  asio::io_context io;
  std::error_code ec;
  SocketCanOptions bad_name;
  bad_name.interface = "a-name-longer-than-ifnamsiz";
  EXPECT_EQ(SocketCanBus::open(io.get_executor(), bad_name, ec), nullptr);
  EXPECT_EQ(ec, std::errc::invalid_argument);

  SocketCanOptions no_batch;
  no_batch.interface = "vcan0";
  no_batch.batch_size = 0;
  EXPECT_EQ(SocketCanBus::open(io.get_executor(), no_batch, ec), nullptr);
  EXPECT_EQ(ec, std::errc::invalid_argument);

  SocketCanOptions no_queue;
  no_queue.interface = "vcan0";
  no_queue.transmit_queue_frames = 0;
  EXPECT_EQ(SocketCanBus::open(io.get_executor(), no_queue, ec), nullptr);
  EXPECT_EQ(ec, std::errc::invalid_argument);
}

TEST(SocketCanBus, MissingInterfaceIsAnErrorNotAnException) {
  asio::io_context io;
  std::error_code ec;
  SocketCanOptions options;
  options.interface = "nocan42";
  EXPECT_EQ(SocketCanBus::open(io.get_executor(), options, ec), nullptr);
  EXPECT_TRUE(ec);
  EXPECT_THROW(SocketCanBus::open(io.get_executor(), options), std::system_error);
}

Frame error_frame(std::uint32_t classes, std::uint8_t ctrl) {
  Frame f;
  f.flags = FrameFlags::error;
  f.id = classes;
  f.len = 8;
  f.data[1] = ctrl;
  return f;
}

TEST(SocketCanBus, ErrorFramesMapToFaultConfinementStates) {
  // Bit values from <linux/can/error.h>.
  constexpr std::uint32_t crtl = 0x04, busoff = 0x40, restarted = 0x100, prot = 0x08;
  using S = BusState;
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x04), S::error_active), S::error_warning);
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x08), S::error_active), S::error_warning);
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x10), S::error_warning), S::error_passive);
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x24), S::error_active), S::error_passive);
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x40), S::error_passive), S::error_active);
  EXPECT_EQ(state_after_error_frame(error_frame(busoff, 0), S::error_passive), S::bus_off);
  EXPECT_EQ(state_after_error_frame(error_frame(restarted, 0), S::bus_off), S::error_active);
  // Classes that say nothing about the state leave it alone.
  EXPECT_EQ(state_after_error_frame(error_frame(prot, 0), S::error_warning), S::error_warning);
  EXPECT_EQ(state_after_error_frame(error_frame(crtl, 0x01), S::error_passive), S::error_passive);
  EXPECT_EQ(state_after_error_frame(Frame::standard(0x40, {}), S::error_passive), S::error_passive);
}

}  // namespace
}  // namespace canbridge::can
