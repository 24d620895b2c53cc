#include "canopen/sdo_transfer.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <utility>

#include "canopen/crc16.hpp"

namespace canbridge::canopen {

namespace {

using sdo::kBlockLastSegment;
using sdo::kBlockSizeIndicated;
using sdo::kCrcSupported;
using sdo::kLastSegment;
using sdo::kSegmentBytes;
using sdo::kSeqnoMask;
using sdo::kSizeIndicated;
using sdo::kToggle;
using sdo::Multiplexer;

constexpr std::uint8_t kMaxBlockSize = 127;
// Byte 0 of an abort; inside a block upload sub-block the only byte 0 with seqno 0.
constexpr std::uint8_t kAbortCommand = 0x80;

constexpr std::uint8_t command_byte(std::uint8_t specifier, std::uint8_t low_bits = 0) {
  return static_cast<std::uint8_t>(specifier << 5 | low_bits);
}

std::uint8_t specifier_of(const can::Frame& f) {
  return static_cast<std::uint8_t>(f.data[0] >> 5);
}

bool toggle_of(const can::Frame& f) {
  return (f.data[0] & kToggle) != 0;
}

// Segments that carry `size` bytes: an empty value still takes one (empty) segment.
std::size_t segments_for(std::size_t size) {
  return std::max<std::size_t>(1, (size + kSegmentBytes - 1) / kSegmentBytes);
}

bool expedited_download(std::size_t size) {
  return size != 0 && size <= sdo::kMaxExpedited;
}

// An initiate response (it names an object) for another object than ours: the late answer to an
// earlier, timed-out transfer on this channel, which must neither end nor disturb this one.
bool answers_another_object(const can::Frame& f, Multiplexer mux) {
  const std::uint8_t specifier = specifier_of(f);
  const bool names_object =
      specifier == sdo::scs::initiate_upload || specifier == sdo::scs::initiate_download ||
      (specifier == sdo::scs::block_download &&
       (f.data[0] & 0x03) == sdo::block_download_ss::initiate) ||
      (specifier == sdo::scs::block_upload && (f.data[0] & 0x01) == sdo::block_upload_ss::initiate);
  return names_object && sdo::read_multiplexer(f) != mux;
}

}  // namespace

// --- construction ------------------------------------------------------------------------------

SdoTransfer SdoTransfer::upload(NodeId node, sdo::Multiplexer mux, SdoTransferOptions options) {
  if (node == 0 || node > kMaxNodeId) throw std::invalid_argument("SDO node id must be 1..127");
  if (options.block_size > kMaxBlockSize) {
    throw std::invalid_argument("SDO block size must be 0..127");
  }
  SdoTransfer t;
  t.node_ = node;
  t.mux_ = mux;
  t.upload_ = true;
  t.options_ = options;
  return t;
}

SdoTransfer SdoTransfer::download(NodeId node, sdo::Multiplexer mux, std::vector<std::uint8_t> data,
                                  SdoTransferOptions options) {
  if (data.size() > std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("SDO download of more than 4 GiB");
  }
  SdoTransfer t = upload(node, mux, options);
  t.upload_ = false;
  t.data_ = std::move(data);
  t.total_ = t.data_.size();
  return t;
}

// --- requests ----------------------------------------------------------------------------------

can::Frame SdoTransfer::request(std::uint8_t command) const {
  can::Frame f;
  f.id = sdo::request_cob(node_);
  f.len = sdo::kFrameLength;
  f.data[0] = command;
  return f;
}

void SdoTransfer::await_answer(TimePoint now, can::Frame frame, std::vector<can::Frame>& out) {
  out.push_back(frame);
  deadline_ = now + options_.timeout;
}

void SdoTransfer::start(TimePoint now, std::vector<can::Frame>& out) {
  if (phase_ != Phase::idle) return;
  // An empty download has nothing to put in a sub-block: it goes segmented, whatever the mode.
  block_ = options_.block_size != 0 && (upload_ || !data_.empty());
  phase_ = Phase::initiate;
  const auto size = static_cast<std::uint32_t>(data_.size());
  if (upload_ && block_) {
    can::Frame f = request(
        command_byte(sdo::ccs::block_upload, kCrcSupported | sdo::block_upload_cs::initiate));
    sdo::write_multiplexer(f, mux_);
    f.data[4] = options_.block_size;
    f.data[5] = options_.protocol_switch_threshold;
    return await_answer(now, f, out);
  }
  if (upload_) return await_answer(now, sdo::upload_request(node_, mux_), out);
  if (block_) {
    can::Frame f =
        request(command_byte(sdo::ccs::block_download, kCrcSupported | kBlockSizeIndicated |
                                                           sdo::block_download_cs::initiate));
    sdo::write_multiplexer(f, mux_);
    sdo::write_u32(f, 4, size);
    return await_answer(now, f, out);
  }
  if (expedited_download(data_.size())) {
    return await_answer(now, sdo::download_request(node_, mux_, data_), out);
  }
  can::Frame f = request(command_byte(sdo::ccs::initiate_download, kSizeIndicated));
  sdo::write_multiplexer(f, mux_);
  sdo::write_u32(f, 4, size);
  await_answer(now, f, out);
}

// --- answers -----------------------------------------------------------------------------------

void SdoTransfer::on_frame(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out) {
  if (phase_ == Phase::idle || phase_ == Phase::done) return;
  if (frame.id != sdo::response_cob(node_) || !sdo::is_sdo_frame(frame)) return;
  switch (phase_) {
    case Phase::initiate:
      return on_initiate(frame, now, out);
    case Phase::segment:
      return on_segment(frame, now, out);
    case Phase::sub_block:
      return upload_ ? on_block_upload_frame(frame, now, out)
                     : on_block_download_answer(frame, now, out);
    case Phase::block_end:
      return upload_ ? on_block_upload_end(frame, out) : on_block_download_answer(frame, now, out);
    case Phase::idle:
    case Phase::done:
      return;
  }
}

bool SdoTransfer::take_server_abort(const can::Frame& frame) {
  if (specifier_of(frame) != sdo::scs::abort) return false;
  const Multiplexer mux = sdo::read_multiplexer(frame);
  // Once past the initiate, a server that lost the transfer (reset, its own timeout) cannot
  // relate our segment to an object and names none; that abort is for us too.
  const bool ours = mux == mux_ || (phase_ != Phase::initiate && mux == Multiplexer{});
  if (ours) finish(abort_error(sdo::read_u32(frame, 4)));
  return true;  // an abort naming another object answers an earlier transfer: ignored
}

void SdoTransfer::on_initiate(const can::Frame& frame, TimePoint now,
                              std::vector<can::Frame>& out) {
  if (take_server_abort(frame)) return;
  // Every initiate response names the object; a frame naming another answers an earlier request.
  if (sdo::read_multiplexer(frame) != mux_) return;
  const std::uint8_t specifier = specifier_of(frame);
  const std::uint8_t command = frame.data[0];
  if (block_ && upload_) {
    if (specifier == sdo::scs::block_upload && (command & 0x01) == sdo::block_upload_ss::initiate) {
      server_crc_ = (command & kCrcSupported) != 0;
      size_indicated_ = (command & kBlockSizeIndicated) != 0;
      total_ = size_indicated_ ? sdo::read_u32(frame, 4) : 0;
      block_size_ = options_.block_size;
      seqno_ = 0;
      phase_ = Phase::sub_block;
      const can::Frame start =
          request(command_byte(sdo::ccs::block_upload, sdo::block_upload_cs::start));
      return await_answer(now, start, out);
    }
    // Below the protocol switch threshold the server may answer as to a plain upload.
    if (specifier == sdo::scs::initiate_upload && options_.protocol_switch_threshold != 0) {
      block_ = false;
      return on_upload_initiate(frame, now, out);
    }
    return fail(SdoAbort::invalid_command, out);
  }
  if (block_) {
    if (specifier != sdo::scs::block_download ||
        (command & 0x03) != sdo::block_download_ss::initiate) {
      return fail(SdoAbort::invalid_command, out);
    }
    server_crc_ = (command & kCrcSupported) != 0;
    block_size_ = frame.data[4];
    if (block_size_ == 0 || block_size_ > kMaxBlockSize) {
      return fail(SdoAbort::invalid_block_size, out);
    }
    return send_sub_block(now, out);
  }
  if (upload_) {
    if (specifier != sdo::scs::initiate_upload) return fail(SdoAbort::invalid_command, out);
    return on_upload_initiate(frame, now, out);
  }
  if (specifier != sdo::scs::initiate_download) return fail(SdoAbort::invalid_command, out);
  if (expedited_download(data_.size())) {
    done_ = data_.size();
    return finish({});
  }
  toggle_ = false;
  send_download_segment(now, out);
}

void SdoTransfer::on_upload_initiate(const can::Frame& frame, TimePoint now,
                                     std::vector<can::Frame>& out) {
  const auto response = sdo::decode_response(frame);
  const auto& r = std::get<sdo::UploadResponse>(*response);
  if (r.expedited) {
    const auto bytes = r.data.span();
    data_.assign(bytes.begin(), bytes.end());
    done_ = total_ = data_.size();
    return finish({});
  }
  size_indicated_ = r.size_indicated;
  total_ = r.size_indicated ? r.size : 0;
  toggle_ = false;
  send_upload_segment_request(now, out);
}

// --- segmented ---------------------------------------------------------------------------------

void SdoTransfer::on_segment(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out) {
  if (take_server_abort(frame) || answers_another_object(frame, mux_)) return;
  if (upload_) return on_upload_segment(frame, now, out);
  on_download_segment(frame, now, out);
}

void SdoTransfer::send_download_segment(TimePoint now, std::vector<can::Frame>& out) {
  const std::size_t length = std::min(kSegmentBytes, data_.size() - done_);
  const bool last = done_ + length == data_.size();
  can::Frame f = request(command_byte(
      sdo::ccs::download_segment,
      static_cast<std::uint8_t>((toggle_ ? kToggle : 0) | (kSegmentBytes - length) << 1 |
                                (last ? kLastSegment : 0))));
  std::copy_n(data_.begin() + static_cast<std::ptrdiff_t>(done_), length, f.data.begin() + 1);
  in_flight_ = length;
  phase_ = Phase::segment;
  await_answer(now, f, out);
}

void SdoTransfer::on_download_segment(const can::Frame& frame, TimePoint now,
                                      std::vector<can::Frame>& out) {
  if (specifier_of(frame) != sdo::scs::download_segment) {
    return fail(SdoAbort::invalid_command, out);
  }
  if (toggle_of(frame) != toggle_) return fail(SdoAbort::toggle_bit, out);
  done_ += in_flight_;
  in_flight_ = 0;
  // At least one segment went out, so all data acknowledged means the last one was.
  if (done_ == data_.size()) return finish({});
  toggle_ = !toggle_;
  send_download_segment(now, out);
}

void SdoTransfer::send_upload_segment_request(TimePoint now, std::vector<can::Frame>& out) {
  phase_ = Phase::segment;
  await_answer(now,
               request(command_byte(sdo::ccs::upload_segment, toggle_ ? kToggle : std::uint8_t{0})),
               out);
}

void SdoTransfer::on_upload_segment(const can::Frame& frame, TimePoint now,
                                    std::vector<can::Frame>& out) {
  if (specifier_of(frame) != sdo::scs::upload_segment) {
    return fail(SdoAbort::invalid_command, out);
  }
  if (toggle_of(frame) != toggle_) return fail(SdoAbort::toggle_bit, out);
  const std::size_t length = kSegmentBytes - ((frame.data[0] >> 1) & 0x07);
  data_.insert(data_.end(), frame.data.begin() + 1,
               frame.data.begin() + 1 + static_cast<std::ptrdiff_t>(length));
  done_ = data_.size();
  if (size_indicated_ && data_.size() > total_) return fail(SdoAbort::length_too_high, out);
  if ((frame.data[0] & kLastSegment) != 0) {
    if (size_indicated_ && data_.size() < total_) return fail(SdoAbort::length_too_low, out);
    return finish({});
  }
  toggle_ = !toggle_;
  send_upload_segment_request(now, out);
}

// --- block download ----------------------------------------------------------------------------

void SdoTransfer::send_sub_block(TimePoint now, std::vector<can::Frame>& out) {
  // Segments restart after the acknowledged data: a partial ack repeats the rest.
  seqno_ = 0;
  last_segment_ = false;
  std::size_t at = acknowledged_;
  while (seqno_ < block_size_ && !last_segment_) {
    const std::size_t length = std::min(kSegmentBytes, data_.size() - at);
    last_segment_ = at + length == data_.size();
    ++seqno_;
    can::Frame f =
        request(static_cast<std::uint8_t>((last_segment_ ? kBlockLastSegment : 0) | seqno_));
    std::copy_n(data_.begin() + static_cast<std::ptrdiff_t>(at), length, f.data.begin() + 1);
    out.push_back(f);
    at += length;
  }
  phase_ = Phase::sub_block;
  deadline_ = now + options_.timeout;
}

void SdoTransfer::on_block_download_answer(const can::Frame& frame, TimePoint now,
                                           std::vector<can::Frame>& out) {
  if (take_server_abort(frame) || answers_another_object(frame, mux_)) return;
  const std::uint8_t command = frame.data[0];
  if (specifier_of(frame) != sdo::scs::block_download) {
    return fail(SdoAbort::invalid_command, out);
  }
  if (phase_ == Phase::block_end) {
    if ((command & 0x03) != sdo::block_download_ss::end)
      return fail(SdoAbort::invalid_command, out);
    return finish({});
  }
  if ((command & 0x03) != sdo::block_download_ss::ack) return fail(SdoAbort::invalid_command, out);
  const std::uint8_t ackseq = frame.data[1];
  const std::uint8_t next_block_size = frame.data[2];
  if (ackseq > seqno_) return fail(SdoAbort::invalid_sequence, out);
  if (next_block_size == 0 || next_block_size > kMaxBlockSize) {
    return fail(SdoAbort::invalid_block_size, out);
  }
  acknowledged_ = std::min(data_.size(), acknowledged_ + ackseq * kSegmentBytes);
  done_ = acknowledged_;
  block_size_ = next_block_size;
  if (ackseq < seqno_ || !last_segment_) return send_sub_block(now, out);
  // All data acknowledged: the end names the last segment's padding and carries the CRC (sent
  // even to a server that does not check it; it then ignores the field).
  const auto unused =
      static_cast<std::uint8_t>(segments_for(data_.size()) * kSegmentBytes - data_.size());
  can::Frame end =
      request(command_byte(sdo::ccs::block_download,
                           static_cast<std::uint8_t>(unused << 2 | sdo::block_download_cs::end)));
  const std::uint16_t crc = crc16_xmodem(data_);
  end.data[1] = static_cast<std::uint8_t>(crc);
  end.data[2] = static_cast<std::uint8_t>(crc >> 8);
  phase_ = Phase::block_end;
  await_answer(now, end, out);
}

// --- block upload ------------------------------------------------------------------------------

void SdoTransfer::on_block_upload_frame(const can::Frame& frame, TimePoint now,
                                        std::vector<can::Frame>& out) {
  const std::uint8_t command = frame.data[0];
  // Inside a sub-block byte 0 is c | seqno; seqno 0 does not exist, so 0x80 is the abort.
  if (command == kAbortCommand) {
    take_server_abort(frame);
    return;
  }
  const std::uint8_t seqno = command & kSeqnoMask;
  if (seqno == 0 || seqno > block_size_) return fail(SdoAbort::invalid_sequence, out);
  deadline_ = now + options_.timeout;  // every segment is an answer
  if (seqno == seqno_ + 1) {
    data_.insert(data_.end(), frame.data.begin() + 1,
                 frame.data.begin() + 1 + static_cast<std::ptrdiff_t>(kSegmentBytes));
    seqno_ = seqno;
    last_segment_ = (command & kBlockLastSegment) != 0;
    // The last segment is padded to 7 bytes: more segments than the size needs is too much.
    if (size_indicated_ && data_.size() > segments_for(total_) * kSegmentBytes) {
      return fail(SdoAbort::length_too_high, out);
    }
    done_ = size_indicated_ ? std::min<std::size_t>(data_.size(), total_) : data_.size();
  }
  // A segment out of order is dropped, but the end of the sub-block still ends it: the ack names
  // the last in-order seqno and the server repeats the rest in the next sub-block.
  if ((command & kBlockLastSegment) == 0 && seqno != block_size_) return;
  can::Frame ack = request(command_byte(sdo::ccs::block_upload, sdo::block_upload_cs::ack));
  ack.data[1] = seqno_;
  ack.data[2] = options_.block_size;
  if (last_segment_) {
    phase_ = Phase::block_end;
  } else {
    block_size_ = options_.block_size;
    seqno_ = 0;
  }
  await_answer(now, ack, out);
}

void SdoTransfer::on_block_upload_end(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (take_server_abort(frame)) return;
  const std::uint8_t command = frame.data[0];
  if (specifier_of(frame) != sdo::scs::block_upload ||
      (command & 0x01) != sdo::block_upload_ss::end) {
    return fail(SdoAbort::invalid_command, out);
  }
  const std::size_t unused = (command >> 2) & 0x07;
  data_.resize(data_.size() - std::min(unused, data_.size()));
  if (size_indicated_ && data_.size() != total_) return fail(SdoAbort::length_mismatch, out);
  if (server_crc_) {
    const auto crc = static_cast<std::uint16_t>(frame.data[1] | frame.data[2] << 8);
    if (crc != crc16_xmodem(data_)) return fail(SdoAbort::crc_error, out);
  }
  out.push_back(request(command_byte(sdo::ccs::block_upload, sdo::block_upload_cs::end)));
  done_ = data_.size();
  finish({});
}

// --- the end -----------------------------------------------------------------------------------

void SdoTransfer::on_timeout(TimePoint now, std::vector<can::Frame>& out) {
  if (phase_ == Phase::idle || phase_ == Phase::done || now < deadline_) return;
  fail(SdoAbort::timeout, out);
}

void SdoTransfer::abort(std::error_code reason, std::vector<can::Frame>& out) {
  if (finished_) return;
  // Before start() the server never heard of the transfer: nothing to tell it.
  if (phase_ != Phase::idle) out.push_back(sdo::abort_request(node_, mux_, to_abort_code(reason)));
  finish(reason);
}

void SdoTransfer::fail(SdoAbort abort, std::vector<can::Frame>& out) {
  out.push_back(sdo::abort_request(node_, mux_, abort));
  finish(make_error_code(abort));
}

void SdoTransfer::finish(std::error_code error) {
  phase_ = Phase::done;
  finished_ = true;
  deadline_ = TimePoint::max();
  result_.error = error;
  if (upload_ && !error) {
    result_.data = std::move(data_);
  }
  // A download's copy of the data (up to megabytes) is not needed any more.
  std::vector<std::uint8_t>().swap(data_);
}

}  // namespace canbridge::canopen
