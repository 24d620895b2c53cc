#include "canopen/frame_decoder.hpp"

#include <array>
#include <chrono>
#include <cstdio>

#include "canopen/pdop.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::canopen {

namespace {

constexpr std::array<const char*, 11> kKindNames = {
    "nmt", "sync", "time", "emcy", "heartbeat", "loader", "sdo", "pdo", "pdop", "lss", "unknown"};

// Bytes shown of a PDO Packet: the rest is elided (packets may be kilobytes).
constexpr std::size_t kShownPacketBytes = 16;

std::string hex_bytes(std::span<const std::uint8_t> bytes, std::size_t limit = can::kMaxPayload) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string s;
  for (std::size_t i = 0; i < bytes.size() && i < limit; ++i) {
    if (i != 0) s += ' ';
    s += kHex[bytes[i] >> 4];
    s += kHex[bytes[i] & 0x0F];
  }
  if (bytes.size() > limit) s += " ...";
  return s;
}

std::string format(const char* fmt, auto... args) {
  char buf[160];
  const int n = std::snprintf(buf, sizeof buf, fmt, args...);
  return std::string(buf, static_cast<std::size_t>(std::max(0, std::min<int>(n, sizeof buf - 1))));
}

std::string mux_text(sdo::Multiplexer mux) {
  return format("%04X:%02X", unsigned{mux.index}, unsigned{mux.sub});
}

std::uint16_t le16(const can::Frame& f, std::size_t at) {
  return static_cast<std::uint16_t>(f.data[at] | f.data[at + 1] << 8);
}

// "object does not exist in the object dictionary (0x06020000)": the category names the code.
std::string abort_text(std::uint32_t code) {
  return abort_error(code).message();
}

// CiA 301 table 21 (emergency error codes): exact codes first, then their class.
const char* emcy_meaning(std::uint16_t code) {
  struct Entry {
    std::uint16_t code;
    const char* text;
  };
  static constexpr Entry kCodes[] = {
      {0x0000, "error reset or no error"},
      {0x1000, "generic error"},
      {0x2000, "current"},
      {0x2100, "current, device input side"},
      {0x2200, "current inside the device"},
      {0x2300, "current, device output side"},
      {0x3000, "voltage"},
      {0x3100, "mains voltage"},
      {0x3200, "voltage inside the device"},
      {0x3300, "output voltage"},
      {0x4000, "temperature"},
      {0x4100, "ambient temperature"},
      {0x4200, "device temperature"},
      {0x5000, "device hardware"},
      {0x6000, "device software"},
      {0x6100, "internal software"},
      {0x6200, "user software"},
      {0x6300, "data set"},
      {0x7000, "additional modules"},
      {0x8000, "monitoring"},
      {0x8100, "communication"},
      {0x8110, "CAN overrun (objects lost)"},
      {0x8120, "CAN in error passive mode"},
      {0x8130, "life guard or heartbeat error"},
      {0x8140, "recovered from bus off"},
      {0x8150, "CAN-ID collision"},
      {0x8200, "protocol error"},
      {0x8210, "PDO not processed due to length error"},
      {0x8220, "PDO length exceeded"},
      {0x8230, "DAM MPDO not processed, destination object not available"},
      {0x8240, "unexpected SYNC data length"},
      {0x8250, "RPDO timeout"},
      {0x9000, "external error"},
      {0xF000, "additional functions"},
      {0xFF00, "device specific"},
  };
  for (const std::uint16_t key : {code, static_cast<std::uint16_t>(code & 0xFF00),
                                  static_cast<std::uint16_t>(code & 0xF000)}) {
    for (const auto& e : kCodes) {
      if (e.code == key) return e.text;
    }
  }
  return "unknown error code";
}

std::string nmt_text(const can::Frame& f, std::optional<NodeId>& target) {
  if (f.len < 1) return "NMT (empty frame)";
  const std::uint8_t cs = f.data[0];
  if (cs == 0xE0 && f.len == 3) {  // docs/nmt-node-id.md
    target = f.data[1];
    return format("NMT change node id %u -> %u", unsigned{f.data[1]}, unsigned{f.data[2]});
  }
  if (cs == 0xE1 && f.len == 6) {
    const std::uint32_t serial = static_cast<std::uint32_t>(
        f.data[2] | f.data[3] << 8 | f.data[4] << 16 | static_cast<std::uint32_t>(f.data[5]) << 24);
    return format("NMT set node id %u on serial number 0x%08X", unsigned{f.data[1]}, serial);
  }
  const char* name = nullptr;
  switch (cs) {
    case nmt::start:
      name = "start";
      break;
    case nmt::stop:
      name = "stop";
      break;
    case nmt::enter_pre_operational:
      name = "enter pre-operational";
      break;
    case nmt::reset_node:
      name = "reset node";
      break;
    case nmt::reset_communication:
      name = "reset communication";
      break;
    default:
      return format("NMT unknown command 0x%02X (%u bytes)", unsigned{cs}, unsigned{f.len});
  }
  if (f.len != 2) return std::string("NMT ") + name + format(" (%u bytes, not 2)", unsigned{f.len});
  if (f.data[1] == 0) return std::string("NMT ") + name + " all nodes";
  target = f.data[1];
  return std::string("NMT ") + name + format(" node %u", unsigned{f.data[1]});
}

std::string time_text(const can::Frame& f) {
  if (f.len != 6) return format("TIME (%u bytes, not 6)", unsigned{f.len});
  const std::uint32_t ms =
      (f.data[0] | f.data[1] << 8 | f.data[2] << 16 | static_cast<std::uint32_t>(f.data[3]) << 24) &
      0x0FFFFFFFU;
  const unsigned days = le16(f, 4);
  using namespace std::chrono;
  const year_month_day date{sys_days{year{1984} / January / 1} + std::chrono::days{days}};
  return format("TIME %04d-%02u-%02u %02u:%02u:%02u.%03u", int{date.year()}, unsigned{date.month()},
                unsigned{date.day()}, ms / 3'600'000, ms / 60'000 % 60, ms / 1000 % 60, ms % 1000);
}

std::string emcy_text(const can::Frame& f, NodeId node, BusLayout layout) {
  if (f.len != 8) return format("EMCY node %u (%u bytes, not 8)", unsigned{node}, unsigned{f.len});
  const std::uint16_t code = le16(f, 0);
  std::string meaning = emcy_meaning(code);
  if (layout == BusLayout::qd && code >= 0xF000) {  // docs/sim-nodes.md: state-change EMCY
    meaning = "state change of subsystems";
    for (unsigned bit = 0; bit < 12; ++bit) {
      if ((code >> bit) & 1U) meaning += " " + std::to_string(bit);
    }
  }
  return format("EMCY node %u code %04X (", unsigned{node}, unsigned{code}) + meaning +
         format(") register %02X data ", unsigned{f.data[2]}) +
         hex_bytes(std::span<const std::uint8_t>(f.data.data() + 3, 5));
}

std::string heartbeat_text(const can::Frame& f, NodeId node) {
  if (f.is_remote()) return format("node guarding request node %u", unsigned{node});
  if (f.len != 1)
    return format("heartbeat node %u (%u bytes, not 1)", unsigned{node}, unsigned{f.len});
  const unsigned state = f.data[0] & 0x7FU;
  if (state == 0) return format("boot-up node %u", unsigned{node});
  std::string s = format("heartbeat node %u ", unsigned{node}) + nmt_state_name(state);
  if (state != 0x04 && state != 0x05 && state != 0x7F) s += format(" (0x%02X)", state);
  if (f.data[0] & 0x80U) s += " toggle 1";
  return s;
}

std::string lss_text(const can::Frame& f, bool from_master) {
  std::string s = from_master ? "LSS master " : "LSS slave ";
  if (f.len < 1) return s + "(empty frame)";
  const unsigned cs = f.data[0];
  const std::uint32_t value =
      f.len >= 5 ? static_cast<std::uint32_t>(f.data[1] | f.data[2] << 8 | f.data[3] << 16 |
                                              static_cast<std::uint32_t>(f.data[4]) << 24)
                 : 0;
  static constexpr const char* kIdentity[] = {"vendor", "product", "revision", "serial"};
  switch (cs) {
    case 0x04:
      return s + "switch state global " + (f.data[1] ? "configuration" : "waiting");
    case 0x11:
      return s + (from_master ? format("configure node id %u", unsigned{f.data[1]})
                              : format("configure node id result %u", unsigned{f.data[1]}));
    case 0x13:
      return s + format("configure bit timing table %u index %u", unsigned{f.data[1]},
                        unsigned{f.data[2]});
    case 0x15:
      return s + format("activate bit timing, delay %u ms", unsigned{le16(f, 1)});
    case 0x17:
      return s + (from_master ? std::string("store configuration")
                              : format("store configuration result %u", unsigned{f.data[1]}));
    case 0x40:
    case 0x41:
    case 0x42:
    case 0x43:
      return s + "switch state selective " + kIdentity[cs - 0x40] + format(" 0x%08X", value);
    case 0x44:
      return s + "switch state selective response";
    case 0x4C:
      return s + "identify non-configured remote slave";
    case 0x4F:
      return s + "identify slave response";
    case 0x50:
      return s + "identify non-configured slave response";
    case 0x5A:
    case 0x5B:
    case 0x5C:
    case 0x5D:
      return s + "inquire " + kIdentity[cs - 0x5A] +
             (from_master ? std::string() : format(" = 0x%08X", value));
    case 0x5E:
      return s + "inquire node id" +
             (from_master ? std::string() : format(" = %u", unsigned{f.data[1]}));
    default:
      if (cs >= 0x46 && cs <= 0x4B) return s + format("identify remote slave (command 0x%02X)", cs);
      return s + format("command 0x%02X", cs);
  }
}

// The PDO of a node-addressed COB-ID: (number, transmit) or nullopt.
struct PdoId {
  unsigned number;
  bool tpdo;
};

std::optional<PdoId> cia301_pdo(std::uint16_t base) {
  if (auto n = pdop::tpdo_number(static_cast<std::uint8_t>(base >> 7))) return PdoId{*n, true};
  if (auto n = pdop::rpdo_number(static_cast<std::uint8_t>(base >> 7))) return PdoId{*n, false};
  return std::nullopt;
}

// docs/sim-nodes.md: qd TPDOs 1..34 over the slots of the PDO and SDO ranges; RPDOs at slot 0.
std::optional<PdoId> qd_pdo(std::uint32_t id) {
  const unsigned base = id & 0x780U;
  const unsigned slot = (id >> 5) & 3U;
  if (base >= 0x180 && base <= 0x500) {
    const unsigned pair = (base - 0x180) / 0x100;  // (0x180, 0x200), (0x280, 0x300), ...
    if ((base - 0x180) % 0x100 == 0) return PdoId{7 * pair + slot + 1, true};
    if (slot == 0) return PdoId{pair + 1, false};
    return PdoId{7 * pair + 4 + slot, true};
  }
  if (slot != 0 && base == 0x580) return PdoId{28 + slot, true};
  if (slot != 0 && base == 0x600) return PdoId{31 + slot, true};
  return std::nullopt;
}

std::string pdo_text(const can::Frame& f, PdoId pdo, NodeId node) {
  std::string s = format("%s%u node %u", pdo.tpdo ? "TPDO" : "RPDO", pdo.number, unsigned{node});
  if (f.is_remote()) return s + " remote request";
  return s + ": " + (f.len == 0 ? std::string("(no data)") : hex_bytes(f.payload()));
}

}  // namespace

const char* to_string(FrameKind kind) {
  return kKindNames[static_cast<std::size_t>(kind)];
}

std::optional<FrameKind> parse_frame_kind(std::string_view name) {
  for (std::size_t i = 0; i < kKindNames.size(); ++i) {
    if (name == kKindNames[i]) return static_cast<FrameKind>(i);
  }
  return std::nullopt;
}

std::string frame_kind_names() {
  std::string s;
  for (const char* name : kKindNames) {
    // Appended, not `"" + std::string(name)`: GCC 12 at -O3 reports a false -Wrestrict in the
    // insert at 0 that operator+(const char*, std::string&&) does.
    if (!s.empty()) s += ' ';
    s += name;
  }
  return s;
}

std::optional<BusLayout> parse_bus_layout(std::string_view name) {
  if (name == "cia301") return BusLayout::cia301;
  if (name == "pdop") return BusLayout::pdop;
  if (name == "qd") return BusLayout::qd;
  return std::nullopt;
}

void FrameDecoder::set_layout(unsigned module, BusLayout layout) {
  layouts_[module] = layout;
}

BusLayout FrameDecoder::layout(unsigned module) const {
  const auto it = layouts_.find(module);
  return it == layouts_.end() ? BusLayout::cia301 : it->second;
}

DecodedFrame FrameDecoder::decode(const can::Frame& f, unsigned module) {
  DecodedFrame d;
  if (f.is_error()) {
    d.text = format("error frame, class 0x%08X", f.id);
    return d;
  }
  if (f.is_extended()) {
    d.text = format("extended id 0x%08X: ", f.id) +
             (f.is_remote() ? std::string("remote request") : hex_bytes(f.payload()));
    return d;
  }
  const std::uint32_t id = f.id;
  const BusLayout bus = layout(module);
  const auto node_of = [&](std::uint32_t mask) { return static_cast<NodeId>(id & mask); };
  if (id == cob::nmt) {
    d.kind = FrameKind::nmt;
    d.text = nmt_text(f, d.node);
    return d;
  }
  if (id == cob::sync) {
    d.kind = FrameKind::sync;
    d.text = f.len == 0   ? std::string("SYNC")
             : f.len == 1 ? format("SYNC counter %u", unsigned{f.data[0]})
                          : format("SYNC (%u bytes)", unsigned{f.len});
    return d;
  }
  if (id == cob::time) {
    d.kind = FrameKind::time;
    d.text = time_text(f);
    return d;
  }
  if (id == cob::lss_master || id == cob::lss_slave) {
    d.kind = FrameKind::lss;
    d.text = lss_text(f, id == cob::lss_master);
    return d;
  }
  if (bus == BusLayout::qd && id > 0x720 && id < 0x740 && f.len == 1 && f.data[0] == 0 &&
      !f.is_remote()) {
    d.kind = FrameKind::loader;
    d.node = node_of(0x1F);
    d.text = format("loader boot-up node %u", unsigned{*d.node});
    return d;
  }
  if (bus == BusLayout::pdop && ((id >= 0x180 && id < 0x580) ||
                                 (id > pdop::kAckBase && id <= pdop::kAckBase + pdop::kMaxNode))) {
    if ((id & 0x1F) != 0) return decode_pdop(f, module);
  }
  if (bus == BusLayout::qd && (id & 0x1F) != 0) {
    if (auto pdo = qd_pdo(id)) {
      d.kind = FrameKind::pdo;
      d.node = node_of(0x1F);
      d.text = pdo_text(f, *pdo, *d.node);
      return d;
    }
  }
  const auto address = split_predefined(id);
  if (!address || (bus != BusLayout::cia301 && (id & 0x60) != 0)) {
    d.text = format("unknown COB-ID 0x%03X: ", id) +
             (f.is_remote() ? std::string("remote request") : hex_bytes(f.payload()));
    return d;
  }
  d.node = address->node;
  switch (address->function_base) {
    case cob::emcy:
      d.kind = FrameKind::emcy;
      d.text = emcy_text(f, address->node, bus);
      return d;
    case cob::heartbeat:
      d.kind = FrameKind::heartbeat;
      d.text = heartbeat_text(f, address->node);
      return d;
    case cob::sdo_rx:
    case cob::sdo_tx:
      return decode_sdo(f, module, address->node, address->function_base == cob::sdo_rx);
    default:
      d.kind = FrameKind::pdo;
      d.text = pdo_text(f, *cia301_pdo(address->function_base), address->node);
      return d;
  }
}

DecodedFrame FrameDecoder::decode_sdo(const can::Frame& f, unsigned module, NodeId node,
                                      bool request) {
  DecodedFrame d{FrameKind::sdo, node, {}};
  d.text = format(request ? "SDO request node %u: " : "SDO response node %u: ", unsigned{node});
  if (f.is_remote() || f.len != sdo::kFrameLength) {
    d.text += format("(%u bytes: not an SDO frame)", unsigned{f.len});
    return d;
  }
  SdoChannel& channel = sdo_[{module, node}];
  const std::uint8_t b0 = f.data[0];
  const unsigned cs = b0 >> 5;
  const sdo::Multiplexer mux = sdo::read_multiplexer(f);
  const std::uint32_t value = sdo::read_u32(f, 4);
  auto& text = d.text;
  const auto segment_data = [&](unsigned unused) {
    const auto bytes = std::span<const std::uint8_t>(f.data.data() + 1, 7 - std::min(unused, 7U));
    return format(" %zu bytes", bytes.size()) + (bytes.empty() ? "" : ": " + hex_bytes(bytes));
  };
  // Block segments carry no command specifier: only the phase of the transfer tells them.
  const bool block_segment =
      b0 != 0x80 && (request ? channel.block_download : channel.block_upload);
  if (block_segment) {
    const unsigned seq = b0 & sdo::kSeqnoMask;
    const bool last = (b0 & sdo::kBlockLastSegment) != 0;
    text += format("block %s segment %u", request ? "download" : "upload", seq) + segment_data(0) +
            (last ? " (last)" : "");
    if (last) {
      (request ? channel.block_download : channel.block_upload) = false;
      channel.final_seq = seq;
    }
    return d;
  }
  if (cs == sdo::ccs::abort) {  // the same specifier in both directions
    text += "abort " + mux_text(mux) + " " + abort_text(value);
    channel = SdoChannel{};
    return d;
  }
  const bool expedited = (b0 & sdo::kExpedited) != 0;
  const bool sized = (b0 & sdo::kSizeIndicated) != 0;
  const unsigned unused_expedited = sized ? (b0 >> 2) & 3U : 0;
  const auto expedited_data = [&] {
    const auto bytes =
        std::span<const std::uint8_t>(f.data.data() + 4, sdo::kMaxExpedited - unused_expedited);
    return hex_bytes(bytes);
  };
  const auto size_text = [&] {
    return sized ? format(", size %u", value) : std::string(", size not indicated");
  };
  const bool toggle = (b0 & sdo::kToggle) != 0;
  const auto via = [&] { return " (" + mux_text(channel.mux) + ")"; };
  if (request) {
    switch (cs) {
      case sdo::ccs::initiate_download:
        channel.mux = mux;
        text += "download " + mux_text(mux) +
                (expedited ? " = " + expedited_data() : " segmented" + size_text());
        return d;
      case sdo::ccs::download_segment: {
        const bool last = (b0 & sdo::kLastSegment) != 0;
        text += format("download segment t=%d", toggle ? 1 : 0) + via() +
                segment_data((b0 >> 1) & 7U) + (last ? " (last)" : "");
        return d;
      }
      case sdo::ccs::initiate_upload:
        channel.mux = mux;
        text += "upload " + mux_text(mux);
        return d;
      case sdo::ccs::upload_segment:
        text += format("upload segment request t=%d", toggle ? 1 : 0) + via();
        return d;
      case sdo::ccs::block_download:
        if ((b0 & 1U) == 0) {
          channel.mux = mux;
          text += "block download " + mux_text(mux) + " initiate" +
                  ((b0 & sdo::kBlockSizeIndicated) ? format(", size %u", value) : std::string()) +
                  ((b0 & sdo::kCrcSupported) ? ", CRC" : "");
        } else {
          text += "block download end" + via() +
                  format(", %u unused bytes, CRC %04X", (b0 >> 2) & 7U, unsigned{le16(f, 1)});
        }
        return d;
      case sdo::ccs::block_upload:
        switch (b0 & 3U) {
          case 0:
            channel.mux = mux;
            text +=
                "block upload " + mux_text(mux) +
                format(" initiate, blksize %u, pst %u", unsigned{f.data[4]}, unsigned{f.data[5]}) +
                ((b0 & sdo::kCrcSupported) ? ", CRC" : "");
            return d;
          case 3:
            channel.block_upload = true;
            text += "block upload start" + via();
            return d;
          case 2:
            if (f.data[1] < channel.final_seq) channel.block_upload = true;  // resend from there
            text += format("block upload ack seq %u, blksize %u", unsigned{f.data[1]},
                           unsigned{f.data[2]}) +
                    via();
            return d;
          default:
            text += "block upload end" + via();
            return d;
        }
      default:
        text += format("reserved command 0x%02X", unsigned{b0});
        return d;
    }
  }
  switch (cs) {
    case sdo::scs::initiate_upload:
      text += "upload " + mux_text(mux) +
              (expedited ? " = " + expedited_data() : " segmented" + size_text());
      return d;
    case sdo::scs::upload_segment: {
      const bool last = (b0 & sdo::kLastSegment) != 0;
      text += format("upload segment t=%d", toggle ? 1 : 0) + via() + segment_data((b0 >> 1) & 7U) +
              (last ? " (last)" : "");
      return d;
    }
    case sdo::scs::initiate_download:
      text += "download " + mux_text(mux) + " OK";
      return d;
    case sdo::scs::download_segment:
      text += format("download segment OK t=%d", toggle ? 1 : 0) + via();
      return d;
    case sdo::scs::block_download:
      switch (b0 & 3U) {
        case 0:
          channel.block_download = true;
          channel.final_seq = 0;
          text += "block download " + mux_text(mux) +
                  format(" accepted, blksize %u", unsigned{f.data[4]}) +
                  ((b0 & sdo::kCrcSupported) ? ", CRC" : "");
          return d;
        case 2:
          if (f.data[1] < channel.final_seq) channel.block_download = true;  // resend from there
          text += format("block download ack seq %u, blksize %u", unsigned{f.data[1]},
                         unsigned{f.data[2]}) +
                  via();
          return d;
        default:
          text += "block download end OK" + via();
          return d;
      }
    case sdo::scs::block_upload:
      if ((b0 & 1U) == 0) {
        channel.final_seq = 0;
        text += "block upload " + mux_text(mux) +
                ((b0 & sdo::kBlockSizeIndicated) ? format(", size %u", value) : std::string()) +
                ((b0 & sdo::kCrcSupported) ? ", CRC" : "");
      } else {
        text += "block upload end" + via() +
                format(", %u unused bytes, CRC %04X", (b0 >> 2) & 7U, unsigned{le16(f, 1)});
      }
      return d;
    default:
      text += format("reserved command 0x%02X", unsigned{b0});
      return d;
  }
}

DecodedFrame FrameDecoder::decode_pdop(const can::Frame& f, unsigned module) {
  DecodedFrame d{FrameKind::pdop, std::nullopt, {}};
  if (f.id > pdop::kAckBase) {
    const auto node = static_cast<NodeId>(f.id & 0x1F);
    d.node = node;
    if (f.is_remote()) {
      d.text = format("PDOP ack request node %u", unsigned{node});
      return d;
    }
    const auto ack = pdop::decode_ack(f);
    if (!ack) {
      d.text = format("PDOP ack node %u malformed: ", unsigned{node}) + hex_bytes(f.payload());
      return d;
    }
    const auto status = static_cast<unsigned>(ack->status);
    static constexpr const char* kAborts[] = {"toggle error", "oversize",       "out of memory",
                                              "timeout",      "short fragment", "sender abort"};
    const std::string status_text = status == 0   ? "in progress"
                                    : status == 1 ? "complete"
                                    : status >= 0x80 && status <= 0x85
                                        ? std::string("abort: ") + kAborts[status - 0x80]
                                        : format("status 0x%02X", status);
    d.text = format("PDOP ack node %u RPDO%u ", unsigned{node}, unsigned{ack->rpdo}) + status_text +
             format(", received %u, credit %u", unsigned{ack->received}, unsigned{ack->credit});
    return d;
  }
  const pdop::FragmentId fid = pdop::decode(f.id);
  d.node = fid.node;
  const auto tpdo = pdop::tpdo_number(fid.function_code);
  const auto rpdo = pdop::rpdo_number(fid.function_code);
  const unsigned number = tpdo ? *tpdo : rpdo.value_or(0);
  std::string& s = d.text;
  s = format("PDOP %s%u node %u", tpdo ? "TPDO" : "RPDO", number, unsigned{fid.node});
  if (f.is_remote()) {
    s += " remote request";
    return d;
  }
  s += format(" t=%d c=%d", fid.toggle ? 1 : 0, fid.continued ? 1 : 0);
  Packet& p = packets_[{module, fid.node, number, tpdo.has_value()}];
  if (!fid.continued && f.len == 0) {
    s += tpdo ? " empty frame (protocol error)" : " sender abort";
    p = Packet{};
    return d;
  }
  s += ": " + hex_bytes(f.payload());
  if (fid.continued && f.len < pdop::kFragmentBytes) {
    s += " (short fragment, packet dropped)";
    p = Packet{};
    return d;
  }
  if (!p.open && fid.toggle) {
    s += " (no first fragment, dropped)";
    return d;
  }
  if (p.open && fid.toggle != p.toggle) {
    s += format(" (toggle error: %zu bytes dropped)", p.bytes.size());
    p = Packet{};
    if (fid.toggle) return d;
  }
  if (!p.open) p = Packet{{}, false, true};
  p.bytes.insert(p.bytes.end(), f.data.begin(), f.data.begin() + f.len);
  p.toggle = !fid.toggle;
  if (p.bytes.size() > pdop::kMaxPacketBytes) {
    s += " (oversize, packet dropped)";
    p = Packet{};
    return d;
  }
  if (!fid.continued) {
    if (p.bytes.size() > f.len) {
      s += format(" -> packet of %zu bytes: ", p.bytes.size()) +
           hex_bytes(p.bytes, kShownPacketBytes);
    }
    p = Packet{};
  }
  return d;
}

bool FrameFilter::matches(const DecodedFrame& decoded, unsigned module_of_frame) const {
  if (module && *module != module_of_frame) return false;
  if (node && decoded.node != node) return false;
  if (!kinds.empty() && std::find(kinds.begin(), kinds.end(), decoded.kind) == kinds.end()) {
    return false;
  }
  return true;
}

}  // namespace canbridge::canopen
