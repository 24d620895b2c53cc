#include "sim/sdo_server.hpp"

#include <algorithm>
#include <stdexcept>
#include <variant>

#include "canopen/crc16.hpp"

namespace canbridge::sim {

namespace sdo = canopen::sdo;
using canopen::SdoAbort;
using sdo::Multiplexer;

namespace {

// Byte 0 bits and segment size: canopen/sdo_codec.hpp.
using sdo::kBlockLastSegment;
using sdo::kBlockSizeIndicated;
using sdo::kCrcSupported;
using sdo::kLastSegment;
using sdo::kSegmentBytes;
using sdo::kSeqnoMask;
using sdo::kToggle;
constexpr std::uint8_t kMaxBlockSize = 127;
constexpr std::uint8_t kClientAbort = 0x80;

namespace upload_cs = sdo::block_upload_cs;
namespace download_cs = sdo::block_download_cs;
namespace download_ss = sdo::block_download_ss;
namespace upload_ss = sdo::block_upload_ss;

constexpr std::uint8_t command_byte(std::uint8_t specifier, std::uint8_t low_bits = 0) {
  return static_cast<std::uint8_t>(specifier << 5 | low_bits);
}

std::uint8_t specifier_of(const can::Frame& f) {
  return static_cast<std::uint8_t>(f.data[0] >> 5);
}

bool is_block_upload(const can::Frame& f, std::uint8_t cs) {
  return specifier_of(f) == sdo::ccs::block_upload && (f.data[0] & 0x03) == cs;
}

bool is_block_download(const can::Frame& f, std::uint8_t cs) {
  return specifier_of(f) == sdo::ccs::block_download && (f.data[0] & 0x01) == cs;
}

// The n field: bits 3..1 in segments, bits 4..2 in block end commands.
std::size_t segment_unused(const can::Frame& f) {
  return (f.data[0] >> 1) & 0x07;
}
std::size_t end_block_unused(const can::Frame& f) {
  return (f.data[0] >> 2) & 0x07;
}

// Unused bytes in the last of the segments carrying `size` bytes; an empty value still takes one
// (empty) segment.
std::uint8_t unused_in_last_segment(std::size_t size) {
  const std::size_t segments = std::max<std::size_t>(1, (size + kSegmentBytes - 1) / kSegmentBytes);
  return static_cast<std::uint8_t>(segments * kSegmentBytes - size);
}

}  // namespace

SdoServer::SdoServer(ObjectDictionary& od, const SdoServerOptions& options)
    : od_(od), options_(options) {
  if (options.node_id == 0 || options.node_id > canopen::kMaxNodeId) {
    throw std::invalid_argument("SDO server node id must be 1..127");
  }
  if (options.max_block_size == 0 || options.max_block_size > kMaxBlockSize) {
    throw std::invalid_argument("SDO block size must be 1..127");
  }
  if (options.timeout.count() <= 0) {
    throw std::invalid_argument("SDO server timeout must be positive");
  }
  if (options.level > SdoLevel::block) throw std::invalid_argument("unknown SDO level");
}

void SdoServer::set_node_id(canopen::NodeId id) {
  if (id == 0 || id > canopen::kMaxNodeId) {
    throw std::invalid_argument("SDO server node id must be 1..127");
  }
  options_.node_id = id;
  reset();
}

void SdoServer::reset() {
  state_ = State::idle;
  mux_ = {};
  deadline_ = TimePoint::max();
  // Release the buffer: a domain transfer may have held megabytes.
  std::vector<std::uint8_t>().swap(data_);
  offset_ = 0;
  toggle_ = false;
  indicated_size_.reset();
  capacity_ = 0;
  overflow_ = SdoAbort::length_mismatch;
  client_crc_ = false;
  block_size_ = 0;
  seqno_ = 0;
  last_segment_ = false;
}

SdoServer::TimePoint SdoServer::next_deadline() const {
  return busy() ? deadline_ : TimePoint::max();
}

void SdoServer::on_tick(TimePoint now, std::vector<can::Frame>& out) {
  if (!busy() || now < deadline_) return;
  ++counters_.timeouts;
  abort(SdoAbort::timeout, out);
}

void SdoServer::on_request(const can::Frame& frame, TimePoint now, std::vector<can::Frame>& out) {
  if (!sdo::is_sdo_frame(frame)) return;
  // Inside a sub-block byte 0 is c | seqno, so only exactly 0x80 (seqno 0 is invalid) can be the
  // client's abort there.
  const bool client_abort = state_ == State::block_download_sub_block
                                ? frame.data[0] == kClientAbort
                                : specifier_of(frame) == sdo::ccs::abort;
  if (client_abort) {
    ++counters_.aborts_received;
    reset();
    return;
  }
  switch (state_) {
    case State::idle:
      dispatch_initiate(frame, out);
      break;
    case State::segmented_download:
      download_segment(frame, out);
      break;
    case State::segmented_upload:
      upload_segment(frame, out);
      break;
    case State::block_download_sub_block:
      block_download_segment(frame, out);
      break;
    case State::block_download_end:
      end_block_download(frame, out);
      break;
    case State::block_upload_start:
      start_block_upload(frame, out);
      break;
    case State::block_upload_ack:
      block_upload_ack(frame, out);
      break;
    case State::block_upload_end:
      end_block_upload(frame, out);
      break;
  }
  // Every request handled inside a transfer is activity: the idle timeout restarts.
  deadline_ = busy() ? now + options_.timeout : TimePoint::max();
}

// --- idle: initiate requests -------------------------------------------------------------------

void SdoServer::dispatch_initiate(const can::Frame& frame, std::vector<can::Frame>& out) {
  switch (specifier_of(frame)) {
    case sdo::ccs::initiate_upload:
      initiate_upload(sdo::read_multiplexer(frame), out);
      return;
    case sdo::ccs::initiate_download:
      initiate_download(frame, out);
      return;
    case sdo::ccs::block_upload:
      if (is_block_upload(frame, upload_cs::initiate)) {
        initiate_block_upload(frame, out);
        return;
      }
      break;
    case sdo::ccs::block_download:
      if (is_block_download(frame, download_cs::initiate)) {
        initiate_block_download(frame, out);
        return;
      }
      break;
    default:
      break;
  }
  // Segment and block follow-up requests carry no object address, so the abort names none.
  abort(Multiplexer{}, SdoAbort::invalid_command, out);
}

void SdoServer::initiate_upload(Multiplexer mux, std::vector<can::Frame>& out) {
  const auto read = od_.read(mux.index, mux.sub);
  if (read.error) return abort(mux, read.error, out);
  if (!read.value.empty() && read.value.size() <= sdo::kMaxExpedited) {
    out.push_back(sdo::upload_response(options_.node_id, mux, read.value));
    ++counters_.transfers_ok;
    return;
  }
  if (options_.level < SdoLevel::segmented) return abort(mux, SdoAbort::invalid_command, out);
  begin(State::segmented_upload, mux);
  data_.assign(read.value.begin(), read.value.end());
  out.push_back(sdo::segmented_upload_response(options_.node_id, mux,
                                               static_cast<std::uint32_t>(data_.size())));
}

void SdoServer::initiate_download(const can::Frame& frame, std::vector<can::Frame>& out) {
  const auto request = sdo::decode_request(frame);
  const auto* r = request ? std::get_if<sdo::DownloadRequest>(&*request) : nullptr;
  if (r == nullptr) return abort(sdo::read_multiplexer(frame), SdoAbort::invalid_command, out);
  if (r->expedited) {
    auto data = r->data.span();
    if (!r->size_indicated) {
      // The client sent 4 bytes without saying how many count; a number's type says it.
      const OdEntry* entry = od_.find(r->mux.index, r->mux.sub);
      if (entry != nullptr && !is_variable_length(entry->type)) {
        data = data.first(std::min(data.size(), fixed_size(entry->type)));
      }
    }
    if (const auto error = od_.write(r->mux.index, r->mux.sub, data)) {
      return abort(r->mux, error, out);
    }
    out.push_back(sdo::download_response(options_.node_id, r->mux));
    ++counters_.transfers_ok;
    return;
  }
  if (options_.level < SdoLevel::segmented) return abort(r->mux, SdoAbort::invalid_command, out);
  const auto size = r->size_indicated ? std::optional<std::uint32_t>(r->size) : std::nullopt;
  const DownloadLimit limit = check_download(r->mux, size);
  if (limit.error) return abort(r->mux, limit.error, out);
  begin(State::segmented_download, r->mux);
  capacity_ = limit.capacity;
  overflow_ = limit.overflow;
  indicated_size_ = size;
  if (size) data_.reserve(*size);
  out.push_back(sdo::download_response(options_.node_id, r->mux));
}

void SdoServer::initiate_block_upload(const can::Frame& frame, std::vector<can::Frame>& out) {
  const Multiplexer mux = sdo::read_multiplexer(frame);
  if (options_.level < SdoLevel::block) return abort(mux, SdoAbort::invalid_command, out);
  const std::uint8_t client_block_size = frame.data[4];
  const std::uint8_t protocol_switch_threshold = frame.data[5];
  if (client_block_size == 0 || client_block_size > kMaxBlockSize) {
    return abort(mux, SdoAbort::invalid_block_size, out);
  }
  const auto read = od_.read(mux.index, mux.sub);
  if (read.error) return abort(mux, read.error, out);
  if (protocol_switch_threshold != 0 && read.value.size() <= protocol_switch_threshold) {
    // CiA 301: small values may go by the SDO upload protocol instead; the answer is an initiate
    // upload response (expedited or segmented) and the client continues accordingly.
    return initiate_upload(mux, out);
  }
  begin(State::block_upload_start, mux);
  data_.assign(read.value.begin(), read.value.end());
  block_size_ = client_block_size;
  client_crc_ = (frame.data[0] & kCrcSupported) != 0;
  can::Frame response_frame = response(command_byte(
      sdo::scs::block_upload, kCrcSupported | kBlockSizeIndicated | upload_ss::initiate));
  sdo::write_multiplexer(response_frame, mux);
  sdo::write_u32(response_frame, 4, static_cast<std::uint32_t>(data_.size()));
  out.push_back(response_frame);
}

void SdoServer::initiate_block_download(const can::Frame& frame, std::vector<can::Frame>& out) {
  const Multiplexer mux = sdo::read_multiplexer(frame);
  if (options_.level < SdoLevel::block) return abort(mux, SdoAbort::invalid_command, out);
  const auto size = (frame.data[0] & kBlockSizeIndicated) != 0
                        ? std::optional<std::uint32_t>(sdo::read_u32(frame, 4))
                        : std::nullopt;
  const DownloadLimit limit = check_download(mux, size);
  if (limit.error) return abort(mux, limit.error, out);
  begin(State::block_download_sub_block, mux);
  capacity_ = limit.capacity;
  overflow_ = limit.overflow;
  indicated_size_ = size;
  if (size) data_.reserve(*size + kSegmentBytes);
  client_crc_ = (frame.data[0] & kCrcSupported) != 0;
  block_size_ = options_.max_block_size;
  can::Frame response_frame =
      response(command_byte(sdo::scs::block_download, kCrcSupported | download_ss::initiate));
  sdo::write_multiplexer(response_frame, mux);
  response_frame.data[4] = block_size_;
  out.push_back(response_frame);
}

SdoServer::DownloadLimit SdoServer::check_download(Multiplexer mux,
                                                   std::optional<std::uint32_t> size) const {
  // The dictionary's own write checks, in its order, minus the ones that need the data.
  const OdEntry* entry = od_.find(mux.index, mux.sub);
  if (entry == nullptr) {
    return {od_.has_object(mux.index) ? SdoAbort::no_sub_index : SdoAbort::no_object};
  }
  if (entry->access == Access::ro || entry->access == Access::constant) {
    return {SdoAbort::write_read_only};
  }
  const std::size_t fixed = fixed_size(entry->type);
  if (!size) {
    // Without an indicated size the data may run up to what the entry takes.
    return fixed != 0 ? DownloadLimit{{}, fixed, SdoAbort::length_too_high}
                      : DownloadLimit{{}, kMaxVariableBytes, SdoAbort::out_of_memory};
  }
  if (fixed != 0 && *size > fixed) return {SdoAbort::length_too_high};
  if (fixed != 0 && *size < fixed) return {SdoAbort::length_too_low};
  if (fixed == 0 && *size > kMaxVariableBytes) return {SdoAbort::out_of_memory};
  return {{}, *size, SdoAbort::length_mismatch};
}

// --- segmented transfers -----------------------------------------------------------------------

void SdoServer::download_segment(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (specifier_of(frame) != sdo::ccs::download_segment) {
    return abort(SdoAbort::invalid_command, out);
  }
  const bool toggle = (frame.data[0] & kToggle) != 0;
  if (toggle != toggle_) return abort(SdoAbort::toggle_bit, out);
  const std::size_t length = kSegmentBytes - segment_unused(frame);
  // Checked per segment so a client cannot make the buffer grow past what the entry takes.
  if (data_.size() + length > capacity_) return abort(overflow_, out);
  data_.insert(data_.end(), frame.data.begin() + 1, frame.data.begin() + 1 + length);
  const can::Frame ack =
      response(command_byte(sdo::scs::download_segment, toggle ? kToggle : std::uint8_t{0}));
  if ((frame.data[0] & kLastSegment) == 0) {
    toggle_ = !toggle_;
    out.push_back(ack);
    return;
  }
  if (indicated_size_ && data_.size() != *indicated_size_) {
    return abort(SdoAbort::length_mismatch, out);
  }
  if (!commit_download(out)) return;
  out.push_back(ack);
  finish();
}

void SdoServer::upload_segment(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (specifier_of(frame) != sdo::ccs::upload_segment) {
    return abort(SdoAbort::invalid_command, out);
  }
  const bool toggle = (frame.data[0] & kToggle) != 0;
  if (toggle != toggle_) return abort(SdoAbort::toggle_bit, out);
  const std::size_t length = std::min(kSegmentBytes, data_.size() - offset_);
  const bool last = offset_ + length == data_.size();
  can::Frame segment = response(command_byte(
      sdo::scs::upload_segment,
      static_cast<std::uint8_t>((toggle ? kToggle : 0) | (kSegmentBytes - length) << 1 |
                                (last ? kLastSegment : 0))));
  std::copy_n(data_.begin() + static_cast<std::ptrdiff_t>(offset_), length,
              segment.data.begin() + 1);
  out.push_back(segment);
  offset_ += length;
  toggle_ = !toggle_;
  if (last) finish();
}

// --- block download ----------------------------------------------------------------------------

void SdoServer::block_download_segment(const can::Frame& frame, std::vector<can::Frame>& out) {
  const std::uint8_t seqno = frame.data[0] & kSeqnoMask;
  const bool last = (frame.data[0] & kBlockLastSegment) != 0;
  if (seqno == 0 || seqno > block_size_) return abort(SdoAbort::invalid_sequence, out);
  if (seqno == seqno_ + 1) {
    // The last segment is padded to 7 bytes; the end command says how many bytes were padding.
    const std::size_t max_segments =
        std::max<std::size_t>(1, (capacity_ + kSegmentBytes - 1) / kSegmentBytes);
    if (data_.size() + kSegmentBytes > max_segments * kSegmentBytes) return abort(overflow_, out);
    data_.insert(data_.end(), frame.data.begin() + 1, frame.data.begin() + 1 + kSegmentBytes);
    seqno_ = seqno;
    last_segment_ = last;
  }
  // A segment out of order is dropped, but the end of the sub-block still ends it: the ack names
  // the last in-order seqno and the client repeats the rest in the next sub-block.
  if (!last && seqno != block_size_) return;
  can::Frame ack = response(command_byte(sdo::scs::block_download, download_ss::ack));
  ack.data[1] = seqno_;
  ack.data[2] = options_.max_block_size;
  out.push_back(ack);
  if (last_segment_) {
    state_ = State::block_download_end;
  } else {
    block_size_ = options_.max_block_size;
    seqno_ = 0;
  }
}

void SdoServer::end_block_download(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (!is_block_download(frame, download_cs::end)) return abort(SdoAbort::invalid_command, out);
  data_.resize(data_.size() - std::min(end_block_unused(frame), data_.size()));
  if (indicated_size_ && data_.size() != *indicated_size_) {
    return abort(SdoAbort::length_mismatch, out);
  }
  if (client_crc_) {
    const auto crc = static_cast<std::uint16_t>(frame.data[1] | frame.data[2] << 8);
    if (crc != canopen::crc16_xmodem(data_)) return abort(SdoAbort::crc_error, out);
  }
  if (!commit_download(out)) return;
  out.push_back(response(command_byte(sdo::scs::block_download, download_ss::end)));
  finish();
}

bool SdoServer::commit_download(std::vector<can::Frame>& out) {
  if (const auto error = od_.write(mux_.index, mux_.sub, data_)) {
    abort(error, out);
    return false;
  }
  return true;
}

// --- block upload ------------------------------------------------------------------------------

void SdoServer::start_block_upload(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (!is_block_upload(frame, upload_cs::start)) return abort(SdoAbort::invalid_command, out);
  send_sub_block(out);
}

void SdoServer::send_sub_block(std::vector<can::Frame>& out) {
  // Segments restart after the acknowledged data, so a partial ack retransmits the rest.
  seqno_ = 0;
  last_segment_ = false;
  std::size_t at = offset_;
  while (seqno_ < block_size_ && !last_segment_) {
    const std::size_t length = std::min(kSegmentBytes, data_.size() - at);
    last_segment_ = at + length == data_.size();
    ++seqno_;
    can::Frame segment;
    segment.id = sdo::response_cob(options_.node_id);
    segment.len = sdo::kFrameLength;
    segment.data[0] = static_cast<std::uint8_t>((last_segment_ ? kBlockLastSegment : 0) | seqno_);
    std::copy_n(data_.begin() + static_cast<std::ptrdiff_t>(at), length, segment.data.begin() + 1);
    out.push_back(segment);
    at += length;
  }
  state_ = State::block_upload_ack;
}

void SdoServer::block_upload_ack(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (!is_block_upload(frame, upload_cs::ack)) return abort(SdoAbort::invalid_command, out);
  const std::uint8_t ackseq = frame.data[1];
  const std::uint8_t next_block_size = frame.data[2];
  if (ackseq > seqno_) return abort(SdoAbort::invalid_sequence, out);
  if (next_block_size == 0 || next_block_size > kMaxBlockSize) {
    return abort(SdoAbort::invalid_block_size, out);
  }
  offset_ = std::min(data_.size(), offset_ + ackseq * kSegmentBytes);
  block_size_ = next_block_size;
  if (ackseq < seqno_ || !last_segment_) return send_sub_block(out);
  // Everything acknowledged: end block upload with n and the CRC (sent even when the client did
  // not ask for it; it then ignores the field).
  can::Frame end = response(command_byte(
      sdo::scs::block_upload,
      static_cast<std::uint8_t>(unused_in_last_segment(data_.size()) << 2 | upload_ss::end)));
  const std::uint16_t crc = canopen::crc16_xmodem(data_);
  end.data[1] = static_cast<std::uint8_t>(crc);
  end.data[2] = static_cast<std::uint8_t>(crc >> 8);
  out.push_back(end);
  state_ = State::block_upload_end;
}

void SdoServer::end_block_upload(const can::Frame& frame, std::vector<can::Frame>& out) {
  if (!is_block_upload(frame, upload_cs::end)) return abort(SdoAbort::invalid_command, out);
  finish();
}

// --- transfer bookkeeping ----------------------------------------------------------------------

can::Frame SdoServer::response(std::uint8_t command) const {
  can::Frame f;
  f.id = sdo::response_cob(options_.node_id);
  f.len = sdo::kFrameLength;
  f.data[0] = command;
  return f;
}

void SdoServer::begin(State state, Multiplexer mux) {
  reset();
  state_ = state;
  mux_ = mux;
}

void SdoServer::finish() {
  ++counters_.transfers_ok;
  reset();
}

void SdoServer::abort(Multiplexer mux, std::error_code error, std::vector<can::Frame>& out) {
  out.push_back(sdo::abort_response(options_.node_id, mux, canopen::to_abort_code(error)));
  ++counters_.aborts_sent;
  reset();
}

}  // namespace canbridge::sim
