#include "tests/system_sdo_noisy/sdo_load_master.hpp"

#include <algorithm>
#include <string>

#include "tests/support/raw_can.hpp"

namespace canbridge::test {
namespace {

using Clock = std::chrono::steady_clock;

constexpr std::uint32_t kSdoRx = 0x600;  // master -> server, + node id
constexpr std::uint32_t kSdoTx = 0x580;  // server -> master, + node id
constexpr std::chrono::milliseconds kCatchUp{100};

std::uint32_t little_endian_u32(const can::Frame& f, std::size_t at) {
  return static_cast<std::uint32_t>(f.data[at]) | static_cast<std::uint32_t>(f.data[at + 1]) << 8 |
         static_cast<std::uint32_t>(f.data[at + 2]) << 16 |
         static_cast<std::uint32_t>(f.data[at + 3]) << 24;
}

bool names_object(const can::Frame& f, SdoObject object) {
  return f.data[1] == static_cast<std::uint8_t>(object.index) &&
         f.data[2] == static_cast<std::uint8_t>(object.index >> 8) && f.data[3] == object.sub;
}

constexpr std::uint16_t kNumberedBase = 0x3000;

// The request a numbered object names, if it is one.
std::optional<std::uint32_t> numbered_seq(const can::Frame& f) {
  const auto index = static_cast<std::uint16_t>(f.data[1] | f.data[2] << 8);
  if (index < kNumberedBase || index >= kNumberedBase + 0x1000) return std::nullopt;
  return static_cast<std::uint32_t>(index - kNumberedBase) << 8 | f.data[3];
}

}  // namespace

SdoObject numbered_object(std::uint32_t seq) {
  return {static_cast<std::uint16_t>(kNumberedBase + (seq >> 8)),
          static_cast<std::uint8_t>(seq & 0xFF)};
}

SdoObject SdoLoadMaster::object_of(std::uint32_t seq) const {
  return options_.numbered_objects ? numbered_object(seq) : SdoObject{options_.index, options_.sub};
}

std::optional<std::uint32_t> load_request_seq(const can::Frame& frame, const SdoLoadOptions& o) {
  if (frame.is_extended() || frame.is_remote() || frame.len != 8) return std::nullopt;
  // 0x23: initiate download, expedited, 4 bytes; 0x40: initiate upload.
  if (frame.data[0] != 0x23 && frame.data[0] != 0x40) return std::nullopt;
  const std::uint32_t seq = little_endian_u32(frame, 4);
  const SdoObject object = o.numbered_objects ? numbered_object(seq) : SdoObject{o.index, o.sub};
  if (!names_object(frame, object)) return std::nullopt;
  return seq;
}

can::Frame SdoLoadMaster::request_frame(std::uint32_t seq, bool download, std::uint8_t node) const {
  const SdoObject object = object_of(seq);
  return can::Frame::standard(
      kSdoRx + node,
      {static_cast<std::uint8_t>(download ? 0x23 : 0x40), static_cast<std::uint8_t>(object.index),
       static_cast<std::uint8_t>(object.index >> 8), object.sub, static_cast<std::uint8_t>(seq),
       static_cast<std::uint8_t>(seq >> 8), static_cast<std::uint8_t>(seq >> 16),
       static_cast<std::uint8_t>(seq >> 24)});
}

void SdoLoadMaster::on_answer(const can::Frame& frame, Clock::time_point now,
                              std::vector<std::optional<std::size_t>>& outstanding) {
  const auto slot = std::find(options_.nodes.begin(), options_.nodes.end(),
                              static_cast<std::uint8_t>(frame.id - kSdoTx));
  const auto i = static_cast<std::size_t>(slot - options_.nodes.begin());
  if (slot == options_.nodes.end() || frame.len != 8) {
    ++stray_answers_;
    return;
  }
  if (options_.numbered_objects) {
    // An answer naming an earlier request of this node, ended already: late (or a second one).
    const auto seq = numbered_seq(frame);
    if (seq && *seq < requests_.size() && requests_[*seq].node == *slot &&
        (!outstanding[i] || *outstanding[i] != *seq)) {
      if (++late_answers_ <= 10) {
        const SdoRequestRecord& ended = requests_[*seq];
        const char* ends[] = {"pending", "response", "abort", "none"};
        late_answer_list_ +=
            " #" + std::to_string(*seq) + " (" +
            (frame.data[0] >> 5 == 4 ? "abort " + std::to_string(little_endian_u32(frame, 4))
                                     : std::string("response")) +
            " after its " + ends[static_cast<int>(ended.end)] + " " +
            std::to_string(ended.abort_code) + ", " +
            std::to_string(
                std::chrono::duration_cast<std::chrono::milliseconds>(now - ended.sent).count()) +
            " ms after it was sent)";
      }
      return;
    }
  }
  if (!outstanding[i] || !names_object(frame, object_of(requests_[*outstanding[i]].seq))) {
    ++stray_answers_;
    return;
  }
  SdoRequestRecord& r = requests_[*outstanding[i]];
  const std::uint8_t scs = frame.data[0] >> 5;
  if (scs == 4) {
    r.end = SdoRequestRecord::End::abort;
    r.abort_code = little_endian_u32(frame, 4);
  } else if ((r.download && scs == 3) || (!r.download && scs == 2)) {
    r.end = SdoRequestRecord::End::response;
  } else {
    ++stray_answers_;  // an answer of the wrong kind: not this request's
    return;
  }
  r.answered = now;
  outstanding[i].reset();
}

void SdoLoadMaster::run(Clock::time_point send_until) {
  std::vector<std::uint32_t> answer_ids;
  for (std::uint8_t node : options_.nodes) answer_ids.push_back(kSdoTx + node);
  RawCanSocket socket(interface_, answer_ids);
  // Per node: the request it has outstanding (an index into requests_).
  std::vector<std::optional<std::size_t>> outstanding(options_.nodes.size());
  std::size_t next_node = 0;
  auto next_send = Clock::now();
  for (;;) {
    auto now = Clock::now();
    auto wake = Clock::time_point::max();
    bool busy = false;
    for (auto& o : outstanding) {
      if (!o) continue;
      SdoRequestRecord& r = requests_[*o];
      if (now - r.sent >= options_.answer_bound) {
        r.end = SdoRequestRecord::End::none;
        o.reset();
        continue;
      }
      busy = true;
      wake = std::min(wake, r.sent + options_.answer_bound);
    }
    const bool sending = now < send_until;
    if (!sending && !busy) return;
    if (sending && now >= next_send) {
      std::size_t tried = 0;
      while (tried < outstanding.size() && outstanding[next_node]) {
        next_node = (next_node + 1) % outstanding.size();
        ++tried;
      }
      if (tried < outstanding.size()) {
        const auto seq = static_cast<std::uint32_t>(requests_.size());
        const bool download = seq % 2 == 0;
        const std::uint8_t node = options_.nodes[next_node];
        SdoRequestRecord& r = requests_.emplace_back();
        r.seq = seq;
        r.node = node;
        r.download = download;
        r.sent = now;
        outstanding[next_node] = requests_.size() - 1;
        socket.send(request_frame(seq, download, node));
        next_node = (next_node + 1) % outstanding.size();
        // A late wake-up (a coarse timer) is made up by the next sends; far behind (every node
        // was busy), the schedule starts anew rather than burst.
        next_send += options_.period;
        if (next_send + kCatchUp < now) next_send = now;
        continue;
      }
      ++all_busy_;  // a node's answer (or the bound) frees one; the frame wakes us
    } else if (sending) {
      wake = std::min(wake, next_send);
    }
    if (sending) wake = std::min(wake, send_until);
    const auto wait = std::chrono::duration_cast<std::chrono::milliseconds>(wake - now) +
                      std::chrono::milliseconds(1);
    if (auto frame = socket.receive(wait)) on_answer(*frame, Clock::now(), outstanding);
  }
}

}  // namespace canbridge::test
