#include "canopen/sdo_transaction_tracker.hpp"

#include <algorithm>
#include <span>

#include "canopen/crc16.hpp"

namespace canbridge::canopen::sdo {

namespace {

// Byte 0 bits and block sub-commands: sdo_codec.hpp.
// Inside a sub-block only exactly this byte 0 is a command (abort): seqno 0 does not exist.
constexpr std::uint8_t kAbortInSubBlock = 0x80;

std::uint8_t specifier_of(const can::Frame& f) {
  return static_cast<std::uint8_t>(f.data[0] >> 5);
}

// The size a listed value has on the wire.
std::size_t value_size(ValueKind kind) {
  return kind == ValueKind::node_id ? 1 : 4;
}

// `kind`, or none when an indicated size says the transfer does not carry exactly the value.
ValueKind checked_kind(ValueKind kind, bool size_indicated, std::uint32_t size) {
  if (kind == ValueKind::none || !size_indicated) return kind;
  return size == value_size(kind) ? kind : ValueKind::none;
}

// Rewrites the value of `kind` at data byte `at` of `frame` in place.
ValueRewrite rewrite_value_at(can::Frame& frame, std::size_t at, ValueKind kind,
                              const IdMapping& map) {
  const std::uint32_t value = kind == ValueKind::node_id ? frame.data[at] : read_u32(frame, at);
  const TranslatedValue t = translate_value(kind, value, map);
  if (!t.mapped) return ValueRewrite::no_counterpart;
  if (t.value == value) return ValueRewrite::unchanged;
  if (kind == ValueKind::node_id) {
    frame.data[at] = static_cast<std::uint8_t>(t.value);
  } else {
    write_u32(frame, at, t.value);
  }
  return ValueRewrite::rewritten;
}

}  // namespace

void ValueTransferTracker::reset() {
  *this = ValueTransferTracker{};
}

void ValueTransferTracker::begin(Phase phase, Multiplexer mux, ValueKind kind) {
  reset();
  phase_ = phase;
  mux_ = mux;
  kind_ = kind;
}

void ValueTransferTracker::confirm(Multiplexer mux) {
  if (mux != mux_) kind_ = ValueKind::none;
}

// --- client -> server --------------------------------------------------------------------------

ValueRewrite ValueTransferTracker::on_request(can::Frame& request, const IdMapping& to_local) {
  confirmed_.reset();
  if (!is_sdo_frame(request)) return ValueRewrite::unchanged;
  if (phase_ == Phase::block_download_sub_block) {
    if (request.data[0] == kAbortInSubBlock) {
      reset();
      return ValueRewrite::unchanged;
    }
    return block_segment(request, to_local);
  }
  if (const auto result = followed_request(request, to_local)) return *result;
  // Aborts, the end of a transfer and frames that do not fit the phase: the transfer is over.
  reset();
  return ValueRewrite::unchanged;
}

std::optional<ValueRewrite> ValueTransferTracker::followed_request(can::Frame& request,
                                                                   const IdMapping& to_local) {
  switch (specifier_of(request)) {
    case ccs::initiate_download:
      return initiate_download(request, to_local);
    case ccs::initiate_upload: {
      const Multiplexer mux = read_multiplexer(request);
      begin(Phase::upload_initiated, mux, value_kind(mux));
      return ValueRewrite::unchanged;
    }
    case ccs::download_segment:
      return download_segment(request, to_local);
    case ccs::upload_segment:
      if (phase_ != Phase::segmented_upload) return std::nullopt;
      return ValueRewrite::unchanged;
    case ccs::block_upload:
      return block_upload_request(request);
    case ccs::block_download:
      return block_download_request(request);
    case ccs::abort:
    default:
      return std::nullopt;
  }
}

std::optional<ValueRewrite> ValueTransferTracker::download_segment(can::Frame& request,
                                                                   const IdMapping& to_local) {
  if (phase_ != Phase::segmented_download || last_sent_) return std::nullopt;
  const std::uint8_t command = request.data[0];
  const std::size_t length = kSegmentBytes - ((command >> 1) & 0x07);
  const bool last = (command & kLastSegment) != 0;
  const bool whole = at_start_ && last && length == value_size(kind_);
  at_start_ = false;
  last_sent_ = last;
  return first_segment(request, whole, to_local);
}

std::optional<ValueRewrite> ValueTransferTracker::block_upload_request(const can::Frame& request) {
  const std::uint8_t command = request.data[0];
  switch (command & 0x03) {
    case block_upload_cs::initiate: {
      const Multiplexer mux = read_multiplexer(request);
      begin(Phase::block_upload_initiated, mux, value_kind(mux));
      client_crc_ = (command & kCrcSupported) != 0;
      return ValueRewrite::unchanged;
    }
    case block_upload_cs::start:
      if (phase_ != Phase::block_upload_start) return std::nullopt;
      phase_ = Phase::block_upload_sub_block;
      last_seqno_ = 0;
      return ValueRewrite::unchanged;
    case block_upload_cs::ack:
      if (phase_ != Phase::block_upload_sub_block) return std::nullopt;
      block_ack(request.data[1], Phase::block_upload_end);
      return ValueRewrite::unchanged;
    case block_upload_cs::end:  // the client's end block upload response closes the transfer
    default:
      return std::nullopt;
  }
}

std::optional<ValueRewrite> ValueTransferTracker::block_download_request(can::Frame& request) {
  const std::uint8_t command = request.data[0];
  if ((command & 0x01) == block_download_cs::initiate) {
    const Multiplexer mux = read_multiplexer(request);
    begin(
        Phase::block_download_initiated, mux,
        checked_kind(value_kind(mux), (command & kBlockSizeIndicated) != 0, read_u32(request, 4)));
    client_crc_ = (command & kCrcSupported) != 0;
    return ValueRewrite::unchanged;
  }
  if ((command & 0x01) == block_download_cs::end && phase_ == Phase::block_download_end) {
    const ValueRewrite result = correct_crc(request);
    reset();
    return result;
  }
  return std::nullopt;
}

ValueRewrite ValueTransferTracker::initiate_download(can::Frame& request,
                                                     const IdMapping& to_local) {
  const std::uint8_t command = request.data[0];
  if ((command & kExpedited) != 0) {
    // Complete in itself; the server's initiate download response ends it.
    reset();
    const ValueRewrite result = rewrite_request(request, to_local);
    const bool size_indicated = (command & kSizeIndicated) != 0;
    const auto size = static_cast<std::uint8_t>(size_indicated ? 4 - ((command >> 2) & 0x03) : 4);
    const std::uint32_t mask = size == 4 ? 0xFFFFFFFFu : (1u << (8 * size)) - 1;
    requested_ = ConfirmedWrite{read_multiplexer(request), read_u32(request, 4) & mask, size};
    return result;
  }
  const Multiplexer mux = read_multiplexer(request);
  begin(Phase::download_initiated, mux,
        checked_kind(value_kind(mux), (command & kSizeIndicated) != 0, read_u32(request, 4)));
  return ValueRewrite::unchanged;
}

// --- server -> client --------------------------------------------------------------------------

ValueRewrite ValueTransferTracker::on_response(can::Frame& response, const IdMapping& to_surface) {
  confirmed_.reset();
  if (!is_sdo_frame(response)) return ValueRewrite::unchanged;
  if (phase_ == Phase::block_upload_sub_block) {
    if (response.data[0] == kAbortInSubBlock) {
      reset();
      return ValueRewrite::unchanged;
    }
    return block_segment(response, to_surface);
  }
  if (const auto result = followed_response(response, to_surface)) return *result;
  // Aborts, the end of a transfer and frames that do not fit the phase: the transfer is over.
  reset();
  return ValueRewrite::unchanged;
}

std::optional<ValueRewrite> ValueTransferTracker::followed_response(can::Frame& response,
                                                                    const IdMapping& to_surface) {
  switch (specifier_of(response)) {
    case scs::initiate_upload:
      return initiate_upload_response(response, to_surface);
    case scs::initiate_download:
      return initiate_download_response(response);
    case scs::download_segment:
      if (phase_ != Phase::segmented_download) return std::nullopt;
      if (last_sent_) reset();  // the last segment confirmed
      return ValueRewrite::unchanged;
    case scs::upload_segment:
      return upload_segment(response, to_surface);
    case scs::block_download:
      return block_download_response(response);
    case scs::block_upload:
      return block_upload_response(response);
    case scs::abort:
    default:
      return std::nullopt;
  }
}

ValueRewrite ValueTransferTracker::initiate_upload_response(can::Frame& response,
                                                            const IdMapping& to_surface) {
  const std::uint8_t command = response.data[0];
  if ((phase_ == Phase::upload_initiated || phase_ == Phase::block_upload_initiated) &&
      (command & kExpedited) == 0) {
    // Segmented (also a block upload answered by the SDO upload protocol).
    confirm(read_multiplexer(response));
    begin(Phase::segmented_upload, mux_,
          checked_kind(kind_, (command & kSizeIndicated) != 0, read_u32(response, 4)));
    at_start_ = true;
    return ValueRewrite::unchanged;
  }
  // Expedited (complete in itself) or unexpected: names its own object.
  reset();
  return rewrite_response(response, to_surface);
}

std::optional<ValueRewrite> ValueTransferTracker::initiate_download_response(
    const can::Frame& response) {
  // The answer to an expedited download: the write it confirms is reported.
  if (phase_ == Phase::idle && requested_ && requested_->mux == read_multiplexer(response)) {
    const ConfirmedWrite write = *requested_;
    reset();
    confirmed_ = write;
    return ValueRewrite::unchanged;
  }
  if (phase_ != Phase::download_initiated) return std::nullopt;
  confirm(read_multiplexer(response));
  phase_ = Phase::segmented_download;
  at_start_ = true;
  return ValueRewrite::unchanged;
}

std::optional<ValueRewrite> ValueTransferTracker::upload_segment(can::Frame& response,
                                                                 const IdMapping& to_surface) {
  if (phase_ != Phase::segmented_upload) return std::nullopt;
  const std::uint8_t command = response.data[0];
  const std::size_t length = kSegmentBytes - ((command >> 1) & 0x07);
  const bool last = (command & kLastSegment) != 0;
  const bool whole = at_start_ && last && length == value_size(kind_);
  at_start_ = false;
  const ValueRewrite result = first_segment(response, whole, to_surface);
  if (last) reset();
  return result;
}

std::optional<ValueRewrite> ValueTransferTracker::block_download_response(
    const can::Frame& response) {
  const std::uint8_t command = response.data[0];
  switch (command & 0x03) {
    case block_download_ss::initiate:
      if (phase_ != Phase::block_download_initiated) return std::nullopt;
      confirm(read_multiplexer(response));
      phase_ = Phase::block_download_sub_block;
      server_crc_ = (command & kCrcSupported) != 0;
      at_start_ = true;
      last_seqno_ = 0;
      return ValueRewrite::unchanged;
    case block_download_ss::ack:
      if (phase_ != Phase::block_download_sub_block) return std::nullopt;
      block_ack(response.data[1], Phase::block_download_end);
      return ValueRewrite::unchanged;
    case block_download_ss::end:  // the server's end block download response
    default:
      return std::nullopt;
  }
}

std::optional<ValueRewrite> ValueTransferTracker::block_upload_response(can::Frame& response) {
  const std::uint8_t command = response.data[0];
  if ((command & 0x01) == block_upload_ss::initiate) {
    if (phase_ != Phase::block_upload_initiated) return std::nullopt;
    confirm(read_multiplexer(response));
    kind_ = checked_kind(kind_, (command & kBlockSizeIndicated) != 0, read_u32(response, 4));
    phase_ = Phase::block_upload_start;
    server_crc_ = (command & kCrcSupported) != 0;
    at_start_ = true;
    return ValueRewrite::unchanged;
  }
  if ((command & 0x01) == block_upload_ss::end && phase_ == Phase::block_upload_end) {
    const ValueRewrite result = correct_crc(response);
    // The client's end block upload response follows; idle reads it as nothing to do.
    reset();
    return result;
  }
  return std::nullopt;
}

// --- shared ------------------------------------------------------------------------------------

ValueRewrite ValueTransferTracker::first_segment(can::Frame& segment, bool whole,
                                                 const IdMapping& map) {
  if (!whole || kind_ == ValueKind::none) return ValueRewrite::unchanged;
  return rewrite_value_at(segment, 1, kind_, map);
}

ValueRewrite ValueTransferTracker::block_segment(can::Frame& segment, const IdMapping& map) {
  const std::uint8_t seqno = segment.data[0] & kSeqnoMask;
  const bool last = (segment.data[0] & kBlockLastSegment) != 0;
  if (last) last_seqno_ = seqno;
  // Only seqno 1 before any data was acknowledged starts the data; with c = 1 it is all of it.
  if (seqno != 1 || !at_start_ || !last || kind_ == ValueKind::none) {
    return ValueRewrite::unchanged;
  }
  std::array<std::uint8_t, kSegmentBytes> before{};
  std::copy_n(segment.data.begin() + 1, kSegmentBytes, before.begin());
  const ValueRewrite result = rewrite_value_at(segment, 1, kind_, map);
  // A repeated seqno 1 (the previous sub-block was acknowledged with 0) replaces the record.
  rewritten_ = result == ValueRewrite::rewritten;
  if (rewritten_) {
    original_ = before;
    std::copy_n(segment.data.begin() + 1, kSegmentBytes, replaced_.begin());
  }
  return result;
}

void ValueTransferTracker::block_ack(std::uint8_t ackseq, Phase end) {
  if (ackseq >= 1) at_start_ = false;
  if (last_seqno_ != 0 && ackseq >= last_seqno_) {
    phase_ = end;
    return;
  }
  // The next sub-block repeats from ackseq + 1, numbered from 1 again.
  last_seqno_ = 0;
}

ValueRewrite ValueTransferTracker::correct_crc(can::Frame& end) {
  if (!rewritten_ || !client_crc_ || !server_crc_) return ValueRewrite::unchanged;
  // n (bits 4..2): bytes of the last (here: the only) segment that were not data.
  const std::size_t unused = (end.data[0] >> 2) & 0x07;
  const std::size_t length = kSegmentBytes - unused;
  const auto original = std::span<const std::uint8_t>(original_).first(length);
  const auto replaced = std::span<const std::uint8_t>(replaced_).first(length);
  const auto delta = static_cast<std::uint16_t>(crc16_xmodem(original) ^ crc16_xmodem(replaced));
  if (delta == 0) return ValueRewrite::unchanged;
  const auto crc = static_cast<std::uint16_t>((end.data[1] | end.data[2] << 8) ^ delta);
  end.data[1] = static_cast<std::uint8_t>(crc);
  end.data[2] = static_cast<std::uint8_t>(crc >> 8);
  return ValueRewrite::rewritten;
}

}  // namespace canbridge::canopen::sdo
