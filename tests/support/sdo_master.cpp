#include "tests/support/sdo_master.hpp"

#include <algorithm>
#include <cstdio>

namespace canbridge::test {

namespace {

constexpr std::uint32_t kRequestBase = 0x600;
constexpr std::uint32_t kResponseBase = 0x580;
constexpr std::size_t kSegment = 7;                  // data bytes per segment
constexpr std::size_t kMaxValue = 16 * 1024 * 1024;  // no test value is longer
// Abort codes the master sends when it gives up.
constexpr std::uint32_t kAbortTimeout = 0x05040000;
constexpr std::uint32_t kAbortCommand = 0x05040001;
constexpr std::uint32_t kAbortCrc = 0x05040004;

std::string hex(std::uint32_t value, int digits) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%0*X", digits, value);
  return buf;
}

std::uint32_t u32_at(const can::Frame& f, std::size_t at) {
  return static_cast<std::uint32_t>(f.data[at]) | static_cast<std::uint32_t>(f.data[at + 1]) << 8 |
         static_cast<std::uint32_t>(f.data[at + 2]) << 16 |
         static_cast<std::uint32_t>(f.data[at + 3]) << 24;
}

// An 8-byte SDO frame: command byte, multiplexer, 4 more bytes (a size, a code or data).
can::Frame sdo_frame(std::uint8_t command, std::uint16_t index, std::uint8_t sub,
                     std::uint32_t value = 0) {
  can::Frame f;
  f.len = 8;
  f.data[0] = command;
  f.data[1] = static_cast<std::uint8_t>(index);
  f.data[2] = static_cast<std::uint8_t>(index >> 8);
  f.data[3] = sub;
  for (std::size_t i = 0; i < 4; ++i) f.data[4 + i] = static_cast<std::uint8_t>(value >> (8 * i));
  return f;
}

bool names(const can::Frame& f, std::uint16_t index, std::uint8_t sub) {
  return f.data[1] == static_cast<std::uint8_t>(index) &&
         f.data[2] == static_cast<std::uint8_t>(index >> 8) && f.data[3] == sub;
}

// A segment (segmented or block): byte 0 as given, then up to 7 data bytes from `data` at
// `offset`, zero padded.
can::Frame segment(std::uint8_t command, std::span<const std::uint8_t> data, std::size_t offset) {
  can::Frame f;
  f.len = 8;
  f.data[0] = command;
  const std::size_t n = std::min(kSegment, data.size() - std::min(offset, data.size()));
  std::copy_n(data.begin() + static_cast<std::ptrdiff_t>(offset), n, f.data.begin() + 1);
  return f;
}

}  // namespace

std::string describe(const SdoOutcome& outcome) {
  std::string s;
  if (outcome.abort) {
    s = "abort 0x" + hex(*outcome.abort, 8);
  } else if (!outcome.failure.empty()) {
    s = "failure: " + outcome.failure;
  } else {
    s = "ok (" + std::to_string(outcome.data.size()) + " bytes)";
  }
  return s + " after " + std::to_string(outcome.elapsed.count()) + " ms";
}

std::uint16_t sdo_block_crc(std::span<const std::uint8_t> data) {
  std::uint16_t crc = 0;
  for (std::uint8_t byte : data) {
    crc = static_cast<std::uint16_t>(crc ^ byte << 8);
    for (int bit = 0; bit < 8; ++bit) {
      crc = static_cast<std::uint16_t>((crc & 0x8000) != 0 ? (crc << 1) ^ 0x1021 : crc << 1);
    }
  }
  return crc;
}

void SdoMaster::send(std::uint8_t node, const can::Frame& request) {
  can::Frame f = request;
  f.id = kRequestBase + node;
  socket_.send(f);
}

std::optional<can::Frame> SdoMaster::next_response(std::uint8_t node) {
  const auto deadline = Clock::now() + options_.timeout;
  for (;;) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
    if (left.count() <= 0) return std::nullopt;
    auto f = socket_.receive(left);
    if (!f) return std::nullopt;
    if (f->id == kResponseBase + node && !f->is_extended() && !f->is_remote()) return f;
  }
}

std::optional<can::Frame> SdoMaster::initiate_answer(std::uint8_t node, std::uint16_t index,
                                                     std::uint8_t sub, SdoOutcome& out) {
  for (;;) {
    auto f = next_response(node);
    if (!f) {
      fail(node, index, sub, out, "no answer to the initiate request", kAbortTimeout);
      return std::nullopt;
    }
    if (f->len != 8 || !names(*f, index, sub)) {
      ++skipped_responses_;  // a late answer about another object
      continue;
    }
    if (is_abort(*f, out)) return std::nullopt;
    return f;
  }
}

bool SdoMaster::is_abort(const can::Frame& answer, SdoOutcome& out) {
  if (answer.len == 8 && answer.data[0] == 0x80) {
    out.abort = u32_at(answer, 4);
    return true;
  }
  return false;
}

void SdoMaster::fail(std::uint8_t node, std::uint16_t index, std::uint8_t sub, SdoOutcome& out,
                     const std::string& why, std::uint32_t code) {
  out.failure =
      "node " + std::to_string(node) + " " + hex(index, 4) + "h:" + hex(sub, 2) + ": " + why;
  send(node, sdo_frame(0x80, index, sub, code));  // let the server go idle
}

SdoOutcome SdoMaster::upload(std::uint8_t node, std::uint16_t index, std::uint8_t sub) {
  const auto start = Clock::now();
  SdoOutcome out;
  const auto finish = [&]() -> SdoOutcome {
    out.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    return out;
  };
  send(node, sdo_frame(0x40, index, sub));
  auto answer = initiate_answer(node, index, sub, out);
  if (!answer) return finish();
  const std::uint8_t command = answer->data[0];
  if (command >> 5 != 2) {
    fail(node, index, sub, out, "initiate upload answered by " + can::to_string(*answer),
         kAbortCommand);
    return finish();
  }
  if ((command & 0x02) != 0) {  // expedited: n unused bytes when the size is indicated
    const std::size_t n = (command & 0x01) != 0 ? 4 - ((command >> 2) & 0x03) : 4;
    out.data.assign(answer->data.begin() + 4, answer->data.begin() + 4 + n);
    return finish();
  }
  const bool size_indicated = (command & 0x01) != 0;
  const std::uint32_t size = u32_at(*answer, 4);
  bool toggle = false;
  for (;;) {
    send(node, sdo_frame(static_cast<std::uint8_t>(0x60 | (toggle ? 0x10 : 0)), 0, 0));
    auto seg = next_response(node);
    if (!seg) {
      fail(node, index, sub, out,
           "no upload segment after " + std::to_string(out.data.size()) + " bytes", kAbortTimeout);
      return finish();
    }
    if (is_abort(*seg, out)) return finish();
    const std::uint8_t c = seg->data[0];
    if (seg->len != 8 || c >> 5 != 0 || ((c & 0x10) != 0) != toggle) {
      fail(node, index, sub, out, "bad upload segment " + can::to_string(*seg), kAbortCommand);
      return finish();
    }
    const std::size_t n = kSegment - ((c >> 1) & 0x07);
    out.data.insert(out.data.end(), seg->data.begin() + 1, seg->data.begin() + 1 + n);
    if ((c & 0x01) != 0) break;
    if (out.data.size() > kMaxValue) {
      fail(node, index, sub, out, "upload longer than any test value", kAbortCommand);
      return finish();
    }
    toggle = !toggle;
  }
  if (size_indicated && out.data.size() != size) {
    out.failure = "segmented upload indicated " + std::to_string(size) + " bytes but carried " +
                  std::to_string(out.data.size());
  }
  return finish();
}

SdoOutcome SdoMaster::download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                               std::span<const std::uint8_t> data) {
  if (data.empty() || data.size() > 4) return segmented_download(node, index, sub, data);
  const auto start = Clock::now();
  SdoOutcome out;
  can::Frame request =
      sdo_frame(static_cast<std::uint8_t>(0x23 | (4 - data.size()) << 2), index, sub);
  std::copy(data.begin(), data.end(), request.data.begin() + 4);
  send(node, request);
  if (auto answer = initiate_answer(node, index, sub, out); answer && answer->data[0] != 0x60) {
    fail(node, index, sub, out, "expedited download answered by " + can::to_string(*answer),
         kAbortCommand);
  }
  out.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
  return out;
}

SdoOutcome SdoMaster::segmented_download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                                         std::span<const std::uint8_t> data) {
  const auto start = Clock::now();
  SdoOutcome out;
  const auto finish = [&]() -> SdoOutcome {
    out.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    return out;
  };
  send(node, sdo_frame(0x21, index, sub, static_cast<std::uint32_t>(data.size())));
  auto answer = initiate_answer(node, index, sub, out);
  if (!answer) return finish();
  if (answer->data[0] != 0x60) {
    fail(node, index, sub, out, "initiate download answered by " + can::to_string(*answer),
         kAbortCommand);
    return finish();
  }
  bool toggle = false;
  std::size_t offset = 0;
  do {
    const std::size_t n = std::min(kSegment, data.size() - offset);
    const bool last = offset + n == data.size();
    send(node, segment(static_cast<std::uint8_t>((toggle ? 0x10 : 0) | (kSegment - n) << 1 |
                                                 (last ? 0x01 : 0)),
                       data, offset));
    offset += n;
    auto ack = next_response(node);
    if (!ack) {
      fail(node, index, sub, out,
           "no download segment answer after " + std::to_string(offset) + " bytes", kAbortTimeout);
      return finish();
    }
    if (is_abort(*ack, out)) return finish();
    if (ack->len != 8 || ack->data[0] != (toggle ? 0x30 : 0x20)) {
      fail(node, index, sub, out, "bad download segment answer " + can::to_string(*ack),
           kAbortCommand);
      return finish();
    }
    toggle = !toggle;
  } while (offset < data.size());
  return finish();
}

SdoOutcome SdoMaster::block_download(std::uint8_t node, std::uint16_t index, std::uint8_t sub,
                                     std::span<const std::uint8_t> data) {
  const auto start = Clock::now();
  SdoOutcome out;
  const auto finish = [&]() -> SdoOutcome {
    out.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    return out;
  };
  // ccs 6, cc (CRC), s (size indicated), cs 0 (initiate).
  send(node, sdo_frame(static_cast<std::uint8_t>(0xC2 | (options_.crc ? 0x04 : 0)), index, sub,
                       static_cast<std::uint32_t>(data.size())));
  auto answer = initiate_answer(node, index, sub, out);
  if (!answer) return finish();
  if ((answer->data[0] & 0xE3) != 0xA0 || answer->data[4] == 0 || answer->data[4] > 127) {
    fail(node, index, sub, out, "initiate block download answered by " + can::to_string(*answer),
         kAbortCommand);
    return finish();
  }
  const bool crc = options_.crc && (answer->data[0] & 0x04) != 0;
  std::uint8_t block_size = answer->data[4];
  // Segments: ceil(size / 7), at least one (an empty value still takes one).
  const std::size_t segments = std::max<std::size_t>(1, (data.size() + kSegment - 1) / kSegment);
  std::size_t acked = 0;  // segments the server confirmed
  while (acked < segments) {
    std::uint8_t sent = 0;
    for (std::size_t s = acked; s < segments && sent < block_size; ++s) {
      ++sent;
      const bool last = s + 1 == segments;
      send(node, segment(static_cast<std::uint8_t>((last ? 0x80 : 0) | sent), data, s * kSegment));
    }
    auto ack = next_response(node);
    if (!ack) {
      fail(node, index, sub, out,
           "no block acknowledgement after segment " + std::to_string(acked + sent), kAbortTimeout);
      return finish();
    }
    if (is_abort(*ack, out)) return finish();
    if (ack->len != 8 || ack->data[0] != 0xA2 || ack->data[1] > sent || ack->data[2] == 0 ||
        ack->data[2] > 127) {
      fail(node, index, sub, out, "bad block acknowledgement " + can::to_string(*ack),
           kAbortCommand);
      return finish();
    }
    acked += ack->data[1];
    block_size = ack->data[2];
  }
  const std::size_t unused = segments * kSegment - data.size();
  const std::uint16_t value_crc = crc ? sdo_block_crc(data) : 0;
  can::Frame end = sdo_frame(static_cast<std::uint8_t>(0xC1 | unused << 2), 0, 0);
  end.data[1] = static_cast<std::uint8_t>(value_crc);
  end.data[2] = static_cast<std::uint8_t>(value_crc >> 8);
  send(node, end);
  auto done = next_response(node);
  if (!done) {
    fail(node, index, sub, out, "no answer to end block download", kAbortTimeout);
  } else if (!is_abort(*done, out) && (done->len != 8 || done->data[0] != 0xA1)) {
    fail(node, index, sub, out, "end block download answered by " + can::to_string(*done),
         kAbortCommand);
  }
  return finish();
}

SdoOutcome SdoMaster::block_upload(std::uint8_t node, std::uint16_t index, std::uint8_t sub) {
  const auto start = Clock::now();
  SdoOutcome out;
  const auto finish = [&]() -> SdoOutcome {
    out.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    return out;
  };
  // ccs 5, cc (CRC), cs 0 (initiate); blksize; pst 0 (never switch to segmented).
  can::Frame initiate =
      sdo_frame(static_cast<std::uint8_t>(0xA0 | (options_.crc ? 0x04 : 0)), index, sub);
  initiate.data[4] = options_.block_size;
  initiate.data[5] = 0;
  send(node, initiate);
  auto answer = initiate_answer(node, index, sub, out);
  if (!answer) return finish();
  if ((answer->data[0] & 0xE1) != 0xC0) {
    fail(node, index, sub, out, "initiate block upload answered by " + can::to_string(*answer),
         kAbortCommand);
    return finish();
  }
  const bool crc = options_.crc && (answer->data[0] & 0x04) != 0;
  const bool size_indicated = (answer->data[0] & 0x02) != 0;
  const std::uint32_t size = u32_at(*answer, 4);
  send(node, sdo_frame(0xA3, 0, 0));  // start upload
  bool last_received = false;
  while (!last_received) {
    std::uint8_t in_order = 0;  // last seqno received in order in this sub-block
    for (;;) {
      auto seg = next_response(node);
      if (!seg) {
        fail(node, index, sub, out,
             "block upload stalled after " + std::to_string(out.data.size()) + " bytes",
             kAbortTimeout);
        return finish();
      }
      if (is_abort(*seg, out)) return finish();
      if (seg->len != 8) {
        fail(node, index, sub, out, "bad block segment " + can::to_string(*seg), kAbortCommand);
        return finish();
      }
      const std::uint8_t seqno = seg->data[0] & 0x7F;
      const bool last = (seg->data[0] & 0x80) != 0;
      if (seqno == in_order + 1) {
        out.data.insert(out.data.end(), seg->data.begin() + 1, seg->data.begin() + 8);
        in_order = seqno;
        last_received = last;
      }
      if (last || seqno >= options_.block_size) break;
      if (out.data.size() > kMaxValue) {
        fail(node, index, sub, out, "block upload longer than any test value", kAbortCommand);
        return finish();
      }
    }
    can::Frame ack = sdo_frame(0xA2, 0, 0);
    ack.data[1] = in_order;
    ack.data[2] = options_.block_size;
    send(node, ack);
  }
  auto end = next_response(node);
  if (!end) {
    fail(node, index, sub, out, "no end block upload", kAbortTimeout);
    return finish();
  }
  if (is_abort(*end, out)) return finish();
  if (end->len != 8 || (end->data[0] & 0xE3) != 0xC1) {
    fail(node, index, sub, out, "bad end block upload " + can::to_string(*end), kAbortCommand);
    return finish();
  }
  const std::size_t unused = (end->data[0] >> 2) & 0x07;
  out.data.resize(out.data.size() - std::min(unused, out.data.size()));
  const auto value_crc = static_cast<std::uint16_t>(end->data[1] | end->data[2] << 8);
  if (crc && value_crc != sdo_block_crc(out.data)) {
    fail(node, index, sub, out, "block upload CRC mismatch", kAbortCrc);
    return finish();
  }
  send(node, sdo_frame(0xA1, 0, 0));  // end block upload response
  if (size_indicated && out.data.size() != size) {
    out.failure = "block upload indicated " + std::to_string(size) + " bytes but carried " +
                  std::to_string(out.data.size());
  }
  return finish();
}

std::optional<std::uint32_t> SdoMaster::read_u32(std::uint8_t node, std::uint16_t index,
                                                 std::uint8_t sub, SdoOutcome* outcome) {
  SdoOutcome o = upload(node, index, sub);
  std::optional<std::uint32_t> value;
  if (o.ok() && !o.data.empty() && o.data.size() <= 4) {
    std::uint32_t v = 0;
    for (std::size_t i = o.data.size(); i-- > 0;) v = v << 8 | o.data[i];
    value = v;
  } else if (o.ok()) {
    o.failure = "expected 1..4 bytes, got " + std::to_string(o.data.size());
  }
  if (outcome != nullptr) *outcome = std::move(o);
  return value;
}

}  // namespace canbridge::test
