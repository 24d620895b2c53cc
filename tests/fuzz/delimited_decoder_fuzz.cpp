// libFuzzer target: DelimitedDecoder (the TCP framing) on an arbitrary stream, fed in chunks the
// input chooses, with every message it yields pushed through the envelope decoding chain.
//
// Input: byte 0 picks max_message_size (0..4080), byte 1 the feeding (low 4 bits: how many
// chunk-size bytes follow, 0 = one chunk), then those chunk-size bytes (each chunk is 1..256
// bytes, cycling), then the stream.
//
// Invariants: the chunking never changes the messages or the error; no message exceeds the
// maximum; an error is sticky; the messages, framed again, decode to themselves.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <system_error>
#include <vector>

#include "backbone/delimited_codec.hpp"
#include "tests/fuzz/envelope_pipeline.hpp"

namespace {

using canbridge::backbone::DelimitedDecoder;
using canbridge::fuzz::require;
using Messages = std::vector<std::vector<std::uint8_t>>;

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

std::error_code decode(DelimitedDecoder& decoder, std::span<const std::uint8_t> input,
                       Messages& messages) {
  return decoder.feed(input, [&](std::span<const std::uint8_t> message) {
    require(message.size() <= decoder.max_message_size(), "message above the maximum size");
    messages.emplace_back(message.begin(), message.end());
  });
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const std::size_t max_message_size = std::size_t{data[0]} * 16;
  const std::size_t plan_size = data[1] & 0x0F;
  if (size < 2 + plan_size) return 0;
  const std::span<const std::uint8_t> plan(data + 2, plan_size);
  const std::span<const std::uint8_t> stream(data + 2 + plan_size, size - 2 - plan_size);

  DelimitedDecoder whole(max_message_size);
  Messages expected;
  const std::error_code expected_error = decode(whole, stream, expected);

  DelimitedDecoder chunked(max_message_size);
  Messages messages;
  std::error_code error;
  std::span<const std::uint8_t> rest = stream;
  for (std::size_t i = 0; !rest.empty(); ++i) {
    const std::size_t chunk_size = plan.empty() ? rest.size() : plan[i % plan.size()] + 1u;
    const auto chunk = rest.first(std::min(chunk_size, rest.size()));
    rest = rest.subspan(chunk.size());
    const std::error_code previous = error;
    error = decode(chunked, chunk, messages);
    require(!previous || error == previous, "an error was not sticky");
  }
  require(messages == expected, "chunking changed the messages");
  require(error == expected_error, "chunking changed the error");
  require(chunked.error() == error, "feed() and error() disagree");
  if (error) {
    require(!chunked.at_message_boundary(), "a poisoned decoder claims a message boundary");
    Messages after_error;
    decode(chunked, stream, after_error);
    require(after_error.empty(), "a poisoned decoder yielded a message");
  }

  std::string reframed;
  for (const auto& message : messages) canbridge::backbone::append_delimited(reframed, message);
  DelimitedDecoder again(max_message_size);
  Messages redecoded;
  require(!decode(again, bytes(reframed), redecoded), "re-framed messages were refused");
  require(redecoded == messages && again.at_message_boundary(), "re-framing changed messages");

  for (const auto& message : messages) canbridge::fuzz::process_envelope(message);
  return 0;
}
