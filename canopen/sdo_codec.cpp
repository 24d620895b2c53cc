#include "canopen/sdo_codec.hpp"

#include <algorithm>
#include <stdexcept>

#include "canopen/little_endian.hpp"

namespace canbridge::canopen::sdo {

namespace {

constexpr std::uint8_t command_byte(std::uint8_t specifier) {
  return static_cast<std::uint8_t>(specifier << 5);
}

can::Frame make(std::uint32_t cob_id, std::uint8_t command, Multiplexer mux) {
  can::Frame f;
  f.id = cob_id;
  f.len = kFrameLength;
  f.data[0] = command;
  write_multiplexer(f, mux);
  return f;
}

// Shared by both initiate directions: the e/s/n bits mean the same in requests and responses.
struct Initiate {
  bool expedited;
  bool size_indicated;
  ExpeditedData data;
  std::uint32_t size;
};

Initiate read_initiate(const can::Frame& f) {
  Initiate out{(f.data[0] & kExpedited) != 0, (f.data[0] & kSizeIndicated) != 0, {}, 0};
  if (out.expedited) {
    out.data.size = out.size_indicated
                        ? static_cast<std::uint8_t>(kMaxExpedited - ((f.data[0] >> 2) & 0x03))
                        : static_cast<std::uint8_t>(kMaxExpedited);
    std::copy_n(f.data.begin() + 4, out.data.size, out.data.bytes.begin());
  } else if (out.size_indicated) {
    out.size = read_u32(f, 4);
  }
  return out;
}

can::Frame make_expedited(std::uint32_t cob_id, std::uint8_t specifier, Multiplexer mux,
                          std::span<const std::uint8_t> data) {
  if (data.empty() || data.size() > kMaxExpedited) {
    throw std::invalid_argument("expedited SDO transfer needs 1..4 data bytes");
  }
  const auto unused = static_cast<std::uint8_t>(kMaxExpedited - data.size());
  can::Frame f = make(cob_id,
                      static_cast<std::uint8_t>(command_byte(specifier) | unused << 2 | kExpedited |
                                                kSizeIndicated),
                      mux);
  std::copy(data.begin(), data.end(), f.data.begin() + 4);
  return f;
}

can::Frame make_abort(std::uint32_t cob_id, Multiplexer mux, std::uint32_t code) {
  can::Frame f = make(cob_id, command_byte(ccs::abort), mux);
  write_u32(f, 4, code);
  return f;
}

}  // namespace

bool is_sdo_frame(const can::Frame& f) {
  return !f.is_extended() && !f.is_remote() && !f.is_error() && f.len == kFrameLength;
}

Multiplexer read_multiplexer(const can::Frame& f) {
  return {static_cast<std::uint16_t>(load_le(std::span(f.data).subspan(1, 2))), f.data[3]};
}

void write_multiplexer(can::Frame& f, Multiplexer mux) {
  store_le(mux.index, std::span(f.data).subspan(1, 2));
  f.data[3] = mux.sub;
}

std::uint32_t read_u32(const can::Frame& f, std::size_t at) {
  return load_le32(std::span(f.data).subspan(at, 4));
}

void write_u32(can::Frame& f, std::size_t at, std::uint32_t value) {
  store_le(value, std::span(f.data).subspan(at, 4));
}

std::optional<Request> decode_request(const can::Frame& frame) {
  if (!is_sdo_frame(frame)) return std::nullopt;
  const auto specifier = static_cast<std::uint8_t>(frame.data[0] >> 5);
  const Multiplexer mux = read_multiplexer(frame);
  switch (specifier) {
    case ccs::initiate_upload:
      return UploadRequest{mux};
    case ccs::initiate_download: {
      const Initiate i = read_initiate(frame);
      return DownloadRequest{mux, i.expedited, i.size_indicated, i.data, i.size};
    }
    case ccs::abort:
      return AbortTransfer{mux, read_u32(frame, 4)};
    default:
      return UnsupportedRequest{specifier, mux};
  }
}

std::optional<Response> decode_response(const can::Frame& frame) {
  if (!is_sdo_frame(frame)) return std::nullopt;
  const auto specifier = static_cast<std::uint8_t>(frame.data[0] >> 5);
  const Multiplexer mux = read_multiplexer(frame);
  switch (specifier) {
    case scs::initiate_upload: {
      const Initiate i = read_initiate(frame);
      return UploadResponse{mux, i.expedited, i.size_indicated, i.data, i.size};
    }
    case scs::initiate_download:
      return DownloadResponse{mux};
    case scs::abort:
      return AbortTransfer{mux, read_u32(frame, 4)};
    default:
      return UnsupportedResponse{specifier, mux};
  }
}

can::Frame upload_request(NodeId node, Multiplexer mux) {
  return make(request_cob(node), command_byte(ccs::initiate_upload), mux);
}

can::Frame download_request(NodeId node, Multiplexer mux, std::span<const std::uint8_t> data) {
  return make_expedited(request_cob(node), ccs::initiate_download, mux, data);
}

can::Frame upload_response(NodeId node, Multiplexer mux, std::span<const std::uint8_t> data) {
  return make_expedited(response_cob(node), scs::initiate_upload, mux, data);
}

can::Frame segmented_upload_response(NodeId node, Multiplexer mux, std::uint32_t size) {
  can::Frame f =
      make(response_cob(node),
           static_cast<std::uint8_t>(command_byte(scs::initiate_upload) | kSizeIndicated), mux);
  write_u32(f, 4, size);
  return f;
}

can::Frame download_response(NodeId node, Multiplexer mux) {
  return make(response_cob(node), command_byte(scs::initiate_download), mux);
}

can::Frame abort_request(NodeId node, Multiplexer mux, std::uint32_t code) {
  return make_abort(request_cob(node), mux, code);
}

can::Frame abort_response(NodeId node, Multiplexer mux, std::uint32_t code) {
  return make_abort(response_cob(node), mux, code);
}

}  // namespace canbridge::canopen::sdo
