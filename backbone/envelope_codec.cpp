#include "backbone/envelope_codec.hpp"

#include <algorithm>

#include "backbone/delimited_codec.hpp"
#include "session.pb.h"

namespace canbridge::backbone {

namespace {

// Envelope field tags (field number << 3 | wire type); each fits one byte.
constexpr std::uint8_t kTagSeq = (v1::Envelope::kSeqFieldNumber << 3) | 0;
constexpr std::uint8_t kTagAck = (v1::Envelope::kAckFieldNumber << 3) | 0;
constexpr std::uint8_t kTagResend = (v1::Envelope::kResendFieldNumber << 3) | 0;
constexpr std::uint8_t kTagKeepalive = (v1::Envelope::kKeepaliveFieldNumber << 3) | 2;
constexpr std::uint8_t kTagPayload = (v1::Envelope::kPayloadFieldNumber << 3) | 2;
constexpr std::uint8_t kTagMissing = (v1::Envelope::kMissingFieldNumber << 3) | 2;  // packed
constexpr std::uint8_t kTagUnreliableSeq = (v1::Envelope::kUnreliableSeqFieldNumber << 3) | 0;
// Keepalive.sent_through, inside the Keepalive body.
constexpr std::uint8_t kTagSentThrough = (v1::Keepalive::kSentThroughFieldNumber << 3) | 0;

// Bytes of a varint field (tag + value), or 0 when the value is the default and left out.
std::size_t varint_field_size(std::uint64_t value) {
  return value == 0 ? 0 : 1 + varint_size(value);
}

std::uint8_t* put_varint_field(std::uint8_t tag, std::uint64_t value, std::uint8_t* p) {
  if (value == 0) return p;
  *p++ = tag;
  return write_varint(value, p);
}

std::size_t missing_bytes(std::span<const std::uint64_t> missing) {
  std::size_t n = 0;
  for (std::uint64_t m : missing) n += varint_size(m);
  return n;
}

// Everything before the body. The body goes last, after fields 8 and 9: the order the wire has
// always had (protobuf parses fields in any order).
std::size_t header_size(const EnvelopeHeader& h, std::size_t missing_len) {
  std::size_t size = varint_field_size(h.seq) + varint_field_size(h.ack);
  if (h.resend) size += 2;
  if (missing_len != 0) size += 1 + varint_size(missing_len) + missing_len;
  return size + varint_field_size(h.unreliable_seq);
}

std::uint8_t* put_header(const EnvelopeHeader& h, std::size_t missing_len, std::uint8_t* p) {
  p = put_varint_field(kTagSeq, h.seq, p);
  p = put_varint_field(kTagAck, h.ack, p);
  if (h.resend) {
    *p++ = kTagResend;
    *p++ = 1;
  }
  if (missing_len != 0) {
    *p++ = kTagMissing;
    p = write_varint(missing_len, p);
    for (std::uint64_t m : h.missing) p = write_varint(m, p);
  }
  return put_varint_field(kTagUnreliableSeq, h.unreliable_seq, p);
}

// Grows `out` by the length prefix of an envelope of `size` bytes plus the envelope, writes the
// prefix and the header, and returns where the body goes.
std::uint8_t* open_envelope(std::string& out, const EnvelopeHeader& h, std::size_t missing_len,
                            std::size_t size) {
  const std::size_t old_size = out.size();
  out.resize(old_size + varint_size(size) + size);
  auto* p = reinterpret_cast<std::uint8_t*>(out.data() + old_size);
  p = write_varint(size, p);
  return put_header(h, missing_len, p);
}

}  // namespace

void append_payload_envelope(std::string& out, const EnvelopeHeader& header,
                             std::span<const std::uint8_t> payload) {
  const std::size_t missing_len = missing_bytes(header.missing);
  const std::size_t size =
      header_size(header, missing_len) + 1 + varint_size(payload.size()) + payload.size();
  std::uint8_t* p = open_envelope(out, header, missing_len, size);
  *p++ = kTagPayload;
  p = write_varint(payload.size(), p);
  std::copy(payload.begin(), payload.end(), p);
}

void append_keepalive_envelope(std::string& out, const EnvelopeHeader& header,
                               std::uint64_t sent_through) {
  const std::size_t missing_len = missing_bytes(header.missing);
  const std::size_t body = varint_field_size(sent_through);  // 0: an empty Keepalive
  const std::size_t size = header_size(header, missing_len) + 1 + varint_size(body) + body;
  std::uint8_t* p = open_envelope(out, header, missing_len, size);
  *p++ = kTagKeepalive;
  p = write_varint(body, p);
  put_varint_field(kTagSentThrough, sent_through, p);
}

}  // namespace canbridge::backbone
