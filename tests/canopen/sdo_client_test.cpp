// The pure SDO client transaction, frame by frame with an injected clock.
#include "canopen/sdo_client.hpp"

#include <gtest/gtest.h>

#include <stdexcept>

namespace canbridge::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;
using TimePoint = SdoClientTransaction::TimePoint;

const TimePoint t0 = TimePoint{} + 1h;

TEST(SdoClientTransaction, UploadSucceedsWithTheServersBytes) {
  auto t = SdoClientTransaction::upload(5, {0x1018, 1}, 100ms);
  EXPECT_EQ(t.start(t0), Frame::standard(0x605, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  EXPECT_EQ(t.deadline(), t0 + 100ms);
  const SdoStep step =
      t.on_frame(Frame::standard(0x585, {0x43, 0x18, 0x10, 0x01, 0x78, 0x56, 0x34, 0x12}), t0);
  EXPECT_FALSE(step.send);
  ASSERT_TRUE(step.result);
  EXPECT_TRUE(step.result->ok()) << step.result->error.message();
  EXPECT_EQ(step.result->data, (std::vector<std::uint8_t>{0x78, 0x56, 0x34, 0x12}));
  EXPECT_TRUE(t.finished());
  EXPECT_EQ(t.deadline(), TimePoint::max());
}

TEST(SdoClientTransaction, IgnoresOtherNodesOtherObjectsAndOtherFrames) {
  auto t = SdoClientTransaction::upload(5, {0x1018, 1}, 100ms);
  t.start(t0);
  const auto ignored = [&](const Frame& f) {
    const SdoStep s = t.on_frame(f, t0);
    return !s.send && !s.result;
  };
  EXPECT_TRUE(ignored(Frame::standard(0x586, {0x43, 0x18, 0x10, 0x01, 1, 2, 3, 4})));  // node 6
  EXPECT_TRUE(ignored(Frame::standard(0x585, {0x43, 0x18, 0x10, 0x02, 1, 2, 3, 4})));  // 1018h:02
  EXPECT_TRUE(ignored(Frame::standard(0x705, {0x7F})));
  EXPECT_TRUE(ignored(Frame::standard(0x585, {0x43, 0x18, 0x10})));  // not 8 bytes
  EXPECT_FALSE(t.finished());
}

TEST(SdoClientTransaction, ServerAbortBecomesTheErrorCode) {
  auto t = SdoClientTransaction::upload(2, {0x2000, 0}, 100ms);
  t.start(t0);
  const SdoStep step =
      t.on_frame(Frame::standard(0x582, {0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x02, 0x06}), t0);
  EXPECT_FALSE(step.send);  // an abort is never answered
  ASSERT_TRUE(step.result);
  EXPECT_EQ(step.result->error, SdoAbort::no_object);
  EXPECT_TRUE(step.result->data.empty());
}

TEST(SdoClientTransaction, TimeoutAbortsWith05040000AndTellsTheServer) {
  auto t = SdoClientTransaction::upload(7, {0x1000, 0}, 50ms);
  t.start(t0);
  const SdoStep early = t.on_timeout(t0 + 49ms);
  EXPECT_FALSE(early.result);
  EXPECT_FALSE(early.send);
  const SdoStep step = t.on_timeout(t0 + 50ms);
  ASSERT_TRUE(step.result);
  EXPECT_EQ(step.result->error, SdoAbort::timeout);
  EXPECT_EQ(step.result->error.value(), 0x05040000);
  ASSERT_TRUE(step.send);
  EXPECT_EQ(*step.send, Frame::standard(0x607, {0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05}));
  // A late response changes nothing.
  EXPECT_FALSE(
      t.on_frame(Frame::standard(0x587, {0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4}), t0 + 60ms).result);
}

TEST(SdoClientTransaction, SegmentedUploadIsAbortedAsUnsupported) {
  auto t = SdoClientTransaction::upload(4, {0x1008, 0}, 100ms);
  t.start(t0);
  const SdoStep step = t.on_frame(sdo::segmented_upload_response(4, {0x1008, 0}, 20), t0);
  ASSERT_TRUE(step.result);
  EXPECT_EQ(step.result->error, SdoAbort::unsupported_access);
  ASSERT_TRUE(step.send);
  EXPECT_EQ(*step.send, sdo::abort_request(4, {0x1008, 0}, SdoAbort::unsupported_access));
}

TEST(SdoClientTransaction, DownloadSucceedsOnDownloadResponse) {
  const std::uint8_t period[] = {0x64, 0x00};
  auto t = SdoClientTransaction::download(1, {0x1017, 0}, period, 100ms);
  EXPECT_EQ(t.start(t0), Frame::standard(0x601, {0x2B, 0x17, 0x10, 0x00, 0x64, 0x00, 0, 0}));
  const SdoStep step = t.on_frame(sdo::download_response(1, {0x1017, 0}), t0);
  ASSERT_TRUE(step.result);
  EXPECT_TRUE(step.result->ok());
}

TEST(SdoClientTransaction, WrongResponseKindIsAProtocolError) {
  const std::uint8_t value[] = {1};
  auto t = SdoClientTransaction::download(1, {0x2000, 0}, value, 100ms);
  t.start(t0);
  const std::uint8_t reply[] = {1};
  const SdoStep step = t.on_frame(sdo::upload_response(1, {0x2000, 0}, reply), t0);
  ASSERT_TRUE(step.result);
  EXPECT_EQ(step.result->error, SdoAbort::invalid_command);
  EXPECT_TRUE(step.send);
}

TEST(SdoClientTransaction, AbortByTheCallerTellsTheServer) {
  auto t = SdoClientTransaction::upload(1, {0x1000, 0}, 100ms);
  t.start(t0);
  const SdoStep step = t.abort(std::make_error_code(std::errc::operation_canceled));
  ASSERT_TRUE(step.result);
  EXPECT_EQ(step.result->error, std::errc::operation_canceled);
  ASSERT_TRUE(step.send);
  EXPECT_EQ(*step.send, sdo::abort_request(1, {0x1000, 0}, SdoAbort::general));
}

TEST(SdoClientTransaction, RejectsInvalidArguments) {
  const std::uint8_t five[] = {1, 2, 3, 4, 5};
  EXPECT_THROW(SdoClientTransaction::upload(0, {0x1000, 0}, 1s), std::invalid_argument);
  EXPECT_THROW(SdoClientTransaction::upload(128, {0x1000, 0}, 1s), std::invalid_argument);
  EXPECT_THROW(SdoClientTransaction::download(1, {0x2000, 0}, five, 1s), std::invalid_argument);
}

}  // namespace
}  // namespace canbridge::canopen
