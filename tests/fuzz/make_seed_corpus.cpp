// Writes the seed corpora of the fuzz targets: real backbone traffic made by the project's own
// encoders, so that the fuzzers start from inputs that pass every parser and mutate from there.
// Usage: make_seed_corpus DIR (creates DIR/<target>/ with a few small files each).
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <span>
#include <string>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "backbone/serial_framing.hpp"
#include "bridge/frame_batch_codec.hpp"
#include "can/frame.hpp"
#include "canbridge.pb.h"
#include "session.pb.h"

namespace {

namespace v1 = canbridge::v1;
using canbridge::can::Frame;
using canbridge::can::FrameFlags;

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

std::string frames_envelope(std::uint64_t seq, const std::vector<Frame>& frames, bool timed,
                            bool head_runs = false) {
  v1::Payload payload;
  canbridge::bridge::FrameBatchBuilder builder(timed, head_runs);
  builder.start(*payload.mutable_frames(), 3);
  for (const Frame& f : frames) builder.append(*payload.mutable_frames(), f);
  v1::Envelope envelope;
  envelope.set_seq(seq);
  envelope.set_ack(seq / 2);
  envelope.set_payload(payload.SerializeAsString());
  return envelope.SerializeAsString();
}

std::vector<std::string> envelopes() {
  std::vector<std::string> out;
  v1::Envelope hello;
  hello.mutable_hello()->set_protocol_major(1);
  hello.mutable_hello()->set_role(v1::Hello::ROLE_GATEWAY);
  hello.mutable_hello()->add_module_ids(3);
  hello.mutable_hello()->set_name("gw");
  hello.mutable_hello()->set_session_id(0x0123456789ABCDEFull);
  hello.mutable_hello()->add_capabilities("reliable");
  out.push_back(hello.SerializeAsString());

  v1::Envelope keepalive;
  keepalive.set_ack(7);
  keepalive.mutable_keepalive();
  out.push_back(keepalive.SerializeAsString());

  v1::Envelope refusal;
  refusal.set_resend(true);
  refusal.mutable_refusal()->set_reason(v1::Refusal::DUPLICATE_MODULE);
  refusal.mutable_refusal()->set_detail("module 3");
  out.push_back(refusal.SerializeAsString());

  Frame remote = Frame::make(0x701, FrameFlags::remote, {});
  remote.len = 1;
  Frame timed = Frame::standard(0x181, {0x11, 0x22});
  timed.timestamp = std::chrono::microseconds(1'700'000'000'000'000);
  out.push_back(frames_envelope(
      1,
      {Frame::standard(0x181, {1, 2, 3, 4, 5, 6, 7, 8}), Frame::standard(0x000, {0x01, 0x00}),
       Frame::make(0x18FF50E5, FrameFlags::extended, {0xAB}), remote},
      false));
  out.push_back(
      frames_envelope(2, {timed, Frame::standard(0x581, {0x43, 0x00, 0x10, 0x00})}, true));
  out.push_back(frames_envelope(3, {}, false));
  // Protocol 2.6 head runs: a run of a standard id, one of an extended id, one of remote frames.
  const Frame ext = Frame::make(0x18FF50E5, FrameFlags::extended, {0xAB});
  Frame later = timed;
  later.timestamp += std::chrono::microseconds(120);
  out.push_back(frames_envelope(
      4, {timed, later, later, Frame::standard(0x182, {}), ext, ext, remote, remote, remote}, true,
      true));
  return out;
}

void write(const std::filesystem::path& dir, const std::string& name, const std::string& data) {
  std::filesystem::create_directories(dir);
  std::ofstream(dir / name, std::ios::binary) << data;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s DIR\n", argv[0]);
    return 2;
  }
  const std::filesystem::path root = argv[1];
  const std::vector<std::string> messages = envelopes();

  std::string stream;
  std::string line(1, static_cast<char>(canbridge::backbone::kFrameDelimiter));  // sender's flush
  for (std::size_t i = 0; i < messages.size(); ++i) {
    write(root / "envelope_fuzz", "envelope-" + std::to_string(i), messages[i]);
    canbridge::backbone::append_delimited(stream, bytes(messages[i]));
    canbridge::backbone::append_serial_frame(line, bytes(messages[i]));
  }
  // Header bytes: max size selector, then the chunking (see each target's comment).
  write(root / "delimited_decoder_fuzz", "stream-one-chunk", std::string("\x40\x00", 2) + stream);
  write(root / "delimited_decoder_fuzz", "stream-chunked",
        std::string("\x40\x03\x00\x06\x1F", 5) + stream);
  write(root / "delimited_decoder_fuzz", "too-large", std::string("\x01\x00\x80\x80\x01", 5));

  const std::string long_payload(300, '\x5A');  // crosses a full 254-byte COBS block
  canbridge::backbone::append_serial_frame(line, bytes(long_payload));
  std::string corrupted;
  canbridge::backbone::append_serial_frame(corrupted, bytes(messages[0]));
  corrupted[2] = static_cast<char>(corrupted[2] ^ 0x04);
  write(root / "serial_deframer_fuzz", "line-one-chunk", std::string("\x64\x00", 2) + line);
  write(root / "serial_deframer_fuzz", "line-pulled-in-chunks",
        std::string("\x64\x12\x02\x0F", 4) + line);
  write(root / "serial_deframer_fuzz", "line-noisy",
        std::string("\x0A\x01\x07", 3) + corrupted + std::string(2, '\0') + line);
  return 0;
}
