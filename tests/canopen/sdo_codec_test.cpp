// SDO wire format (CiA 301 7.2.4.3) and abort codes; byte layouts checked against the standard's
// command bytes: 0x40 upload request, 0x4F/0x4B/0x43 expedited upload response of 1/2/4 bytes,
// 0x2F/0x2B/0x23 expedited download of 1/2/4 bytes, 0x60 download response, 0x80 abort.
#include "canopen/sdo_codec.hpp"

#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "canopen/sdo_abort.hpp"

namespace canbridge::canopen {
namespace {

using can::Frame;

template <typename T, typename V>
T get(const std::optional<V>& decoded) {
  EXPECT_TRUE(decoded.has_value());
  EXPECT_TRUE(std::holds_alternative<T>(*decoded));
  return std::get<T>(*decoded);
}

TEST(SdoCodec, UploadRequestLayoutAndRoundTrip) {
  const Frame f = sdo::upload_request(5, {0x1018, 0x01});
  EXPECT_EQ(f, Frame::standard(0x605, {0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0}));
  const auto r = get<sdo::UploadRequest>(sdo::decode_request(f));
  EXPECT_EQ(r.mux, (sdo::Multiplexer{0x1018, 0x01}));
}

TEST(SdoCodec, ExpeditedDownloadRequestEncodesSizeInN) {
  const std::uint8_t one[] = {0x11};
  const std::uint8_t two[] = {0xE8, 0x03};
  const std::uint8_t four[] = {1, 2, 3, 4};
  EXPECT_EQ(sdo::download_request(1, {0x2000, 0}, one),
            Frame::standard(0x601, {0x2F, 0x00, 0x20, 0x00, 0x11, 0, 0, 0}));
  EXPECT_EQ(sdo::download_request(1, {0x1017, 0}, two),
            Frame::standard(0x601, {0x2B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0, 0}));
  EXPECT_EQ(sdo::download_request(127, {0x2001, 7}, four),
            Frame::standard(0x67F, {0x23, 0x01, 0x20, 0x07, 1, 2, 3, 4}));

  const auto r =
      get<sdo::DownloadRequest>(sdo::decode_request(sdo::download_request(1, {0x1017, 0}, two)));
  EXPECT_TRUE(r.expedited);
  EXPECT_TRUE(r.size_indicated);
  EXPECT_EQ(r.mux, (sdo::Multiplexer{0x1017, 0}));
  ASSERT_EQ(r.data.size, 2);
  EXPECT_EQ(r.data.bytes[0], 0xE8);
  EXPECT_EQ(r.data.bytes[1], 0x03);
}

TEST(SdoCodec, ExpeditedWithoutSizeYieldsAllFourBytes) {
  const auto r = get<sdo::DownloadRequest>(
      sdo::decode_request(Frame::standard(0x601, {0x22, 0x17, 0x10, 0x00, 0x64, 0, 0, 0})));
  EXPECT_TRUE(r.expedited);
  EXPECT_FALSE(r.size_indicated);
  EXPECT_EQ(r.data.size, 4);
}

TEST(SdoCodec, UploadResponseLayoutAndRoundTrip) {
  const std::uint8_t one[] = {0x04};
  const std::uint8_t four[] = {0x91, 0x01, 0x00, 0x00};
  EXPECT_EQ(sdo::upload_response(3, {0x1018, 0}, one),
            Frame::standard(0x583, {0x4F, 0x18, 0x10, 0x00, 0x04, 0, 0, 0}));
  const Frame f = sdo::upload_response(3, {0x1000, 0}, four);
  EXPECT_EQ(f, Frame::standard(0x583, {0x43, 0x00, 0x10, 0x00, 0x91, 0x01, 0x00, 0x00}));
  const auto r = get<sdo::UploadResponse>(sdo::decode_response(f));
  EXPECT_TRUE(r.expedited);
  EXPECT_EQ(r.mux, (sdo::Multiplexer{0x1000, 0}));
  EXPECT_EQ(std::vector<std::uint8_t>(r.data.span().begin(), r.data.span().end()),
            std::vector<std::uint8_t>(std::begin(four), std::end(four)));
}

TEST(SdoCodec, SegmentedUploadResponseCarriesTheSize) {
  const Frame f = sdo::segmented_upload_response(3, {0x1008, 0}, 0x123);
  EXPECT_EQ(f, Frame::standard(0x583, {0x41, 0x08, 0x10, 0x00, 0x23, 0x01, 0, 0}));
  const auto r = get<sdo::UploadResponse>(sdo::decode_response(f));
  EXPECT_FALSE(r.expedited);
  EXPECT_TRUE(r.size_indicated);
  EXPECT_EQ(r.size, 0x123u);
}

TEST(SdoCodec, DownloadResponseLayoutAndRoundTrip) {
  const Frame f = sdo::download_response(9, {0x1017, 0});
  EXPECT_EQ(f, Frame::standard(0x589, {0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0}));
  EXPECT_EQ(get<sdo::DownloadResponse>(sdo::decode_response(f)).mux, (sdo::Multiplexer{0x1017, 0}));
}

TEST(SdoCodec, AbortLayoutIsLittleEndianBothDirections) {
  const Frame server = sdo::abort_response(2, {0x2000, 0}, SdoAbort::no_object);
  EXPECT_EQ(server, Frame::standard(0x582, {0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x02, 0x06}));
  const Frame client = sdo::abort_request(2, {0x1018, 4}, SdoAbort::timeout);
  EXPECT_EQ(client, Frame::standard(0x602, {0x80, 0x18, 0x10, 0x04, 0x00, 0x00, 0x04, 0x05}));

  const auto a = get<sdo::AbortTransfer>(sdo::decode_response(server));
  EXPECT_EQ(a.code, 0x06020000u);
  EXPECT_EQ(a.error(), SdoAbort::no_object);
  EXPECT_EQ(get<sdo::AbortTransfer>(sdo::decode_request(client)).error(), SdoAbort::timeout);
}

TEST(SdoCodec, SegmentAndBlockCommandsDecodeAsUnsupported) {
  const auto seg = get<sdo::UnsupportedRequest>(
      sdo::decode_request(Frame::standard(0x601, {0x60, 0, 0, 0, 0, 0, 0, 0})));
  EXPECT_EQ(seg.command, sdo::ccs::upload_segment);
  const auto block = get<sdo::UnsupportedRequest>(
      sdo::decode_request(Frame::standard(0x601, {0xA4, 0x00, 0x10, 0x00, 0x7F, 0, 0, 0})));
  EXPECT_EQ(block.command, sdo::ccs::block_upload);
  EXPECT_EQ(block.mux, (sdo::Multiplexer{0x1000, 0}));
  const auto resp = get<sdo::UnsupportedResponse>(
      sdo::decode_response(Frame::standard(0x581, {0x00, 1, 2, 3, 4, 5, 6, 7})));
  EXPECT_EQ(resp.command, sdo::scs::upload_segment);
}

TEST(SdoCodec, NonSdoFramesDoNotDecode) {
  EXPECT_FALSE(sdo::decode_request(Frame::standard(0x601, {0x40, 0x00, 0x10, 0x00})));
  Frame rtr = Frame::standard(0x601, {0, 0, 0, 0, 0, 0, 0, 0});
  rtr.flags = can::FrameFlags::remote;
  EXPECT_FALSE(sdo::decode_request(rtr));
  Frame ext = Frame::standard(0x601, {0x40, 0, 0x10, 0, 0, 0, 0, 0});
  ext.flags = can::FrameFlags::extended;
  EXPECT_FALSE(sdo::decode_response(ext));
}

TEST(SdoCodec, ExpeditedBuildersRejectSizesOutsideOneToFour) {
  const std::uint8_t five[] = {1, 2, 3, 4, 5};
  EXPECT_THROW(sdo::download_request(1, {0x2000, 0}, {}), std::invalid_argument);
  EXPECT_THROW(sdo::upload_response(1, {0x2000, 0}, five), std::invalid_argument);
}

TEST(SdoAbortCategory, NamesAndMessages) {
  const std::error_code ec = SdoAbort::no_object;
  EXPECT_STREQ(ec.category().name(), "canopen.sdo");
  EXPECT_EQ(&ec.category(), &sdo_category());
  EXPECT_EQ(ec.value(), 0x06020000);
  EXPECT_EQ(ec.message(), "object does not exist in the object dictionary (0x06020000)");
  EXPECT_EQ(make_error_code(SdoAbort::timeout).message(), "SDO protocol timed out (0x05040000)");
  EXPECT_EQ(abort_error(0x0BADC0DE).message(), "unknown SDO abort code 0x0BADC0DE");
  EXPECT_EQ(abort_error(0x06090011), SdoAbort::no_sub_index);
  EXPECT_NE(abort_error(0x06090011), std::errc::invalid_argument);
}

TEST(SdoAbortCategory, WireCodeForAnyError) {
  EXPECT_EQ(to_abort_code(SdoAbort::write_read_only), 0x06010002u);
  EXPECT_EQ(to_abort_code(std::make_error_code(std::errc::timed_out)), 0x05040000u);
  EXPECT_EQ(to_abort_code(std::make_error_code(std::errc::operation_canceled)), 0x08000000u);
}

}  // namespace
}  // namespace canbridge::canopen
