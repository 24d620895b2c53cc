// Writes a session Envelope (proto/session.proto) by hand around a payload the caller still
// holds, so the hot path never copies a payload into a message object just to serialize it.
#pragma once

#include <cstdint>
#include <span>
#include <string>

namespace canbridge::backbone {

// The fields an envelope written by hand carries besides its body; zero / empty: left out, as
// protobuf leaves out a proto3 default.
struct EnvelopeHeader {
  std::uint64_t seq = 0;                        // Envelope.seq: position in the reliable stream
  std::uint64_t ack = 0;                        // Envelope.ack: cumulative acknowledgement
  bool resend = false;                          // Envelope.resend: the receiver saw a gap after ack
  std::span<const std::uint64_t> missing = {};  // Envelope.missing (packed): further holes
  std::uint64_t unreliable_seq = 0;             // Envelope.unreliable_seq: numbered process data
};

// Appends one delimited envelope (length prefix, then the Envelope) whose body is `payload`.
void append_payload_envelope(std::string& out, const EnvelopeHeader& header,
                             std::span<const std::uint8_t> payload);

// Appends one delimited envelope whose body is a Keepalive (it carries the header: an ack, a
// resend request) naming the highest reliable seq written so far (`sent_through`, 0: none).
void append_keepalive_envelope(std::string& out, const EnvelopeHeader& header,
                               std::uint64_t sent_through = 0);

}  // namespace canbridge::backbone
