#include "backbone/cobs.hpp"

#include <algorithm>

namespace canbridge::backbone {

namespace {

constexpr std::uint8_t kFullBlockCode = 0xFF;  // 254 data bytes and no implied zero

}  // namespace

void cobs_encode(std::span<const std::uint8_t> in, std::string& out) {
  out.reserve(out.size() + cobs_max_encoded_size(in.size()));
  CobsEncoder encoder(out);
  encoder.add(in);
  encoder.finish();
}

CobsEncoder::CobsEncoder(std::string& out) : out_(out) {
  open_block();
}

void CobsEncoder::open_block() {
  code_position_ = out_.size();
  out_.push_back('\x01');  // placeholder, overwritten by close_block()
  code_ = 1;
  block_open_ = true;
}

void CobsEncoder::close_block() {
  out_[code_position_] = static_cast<char>(code_);
  block_open_ = false;
}

void CobsEncoder::add(std::span<const std::uint8_t> bytes) {
  while (!bytes.empty()) {
    // A full block is closed eagerly but its successor opened lazily: a message that ends right
    // after a full block needs no further code byte.
    if (!block_open_) open_block();
    if (bytes.front() == 0) {
      close_block();  // the code stands for the zero
      open_block();
      bytes = bytes.subspan(1);
      continue;
    }
    // Copy the run of non-zero bytes that still fits into this block in one go.
    const std::size_t room = kFullBlockCode - code_;
    const auto window = bytes.first(std::min(room, bytes.size()));
    const std::size_t run =
        static_cast<std::size_t>(std::find(window.begin(), window.end(), 0) - window.begin());
    out_.append(reinterpret_cast<const char*>(window.data()), run);
    code_ = static_cast<std::uint8_t>(code_ + run);
    bytes = bytes.subspan(run);
    if (code_ == kFullBlockCode) close_block();
  }
}

void CobsEncoder::finish() {
  if (block_open_) close_block();
}

bool cobs_decode(std::span<const std::uint8_t> in, std::vector<std::uint8_t>& out) {
  if (in.empty()) return false;  // even the empty message has a code byte
  const std::size_t original_size = out.size();
  std::size_t position = 0;
  while (position < in.size()) {
    const std::uint8_t code = in[position++];
    if (code == 0 || std::size_t{code} - 1 > in.size() - position) {
      out.resize(original_size);
      return false;
    }
    const std::size_t data_bytes = std::size_t{code} - 1;
    const auto data = in.subspan(position, data_bytes);
    if (std::find(data.begin(), data.end(), 0) != data.end()) {
      out.resize(original_size);
      return false;
    }
    out.insert(out.end(), data.begin(), data.end());
    position += data_bytes;
    // The zero a short block stands for is implied only between blocks, never at the end.
    if (code != kFullBlockCode && position < in.size()) out.push_back(0);
  }
  return true;
}

}  // namespace canbridge::backbone
