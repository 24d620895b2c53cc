#include "bridge/statistics_text.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <numeric>

namespace canbridge::bridge {

namespace {

constexpr std::array<can::BusState, 4> kBusStates = {
    can::BusState::error_active, can::BusState::error_warning, can::BusState::error_passive,
    can::BusState::bus_off};

// "812", "1.2k", "3.4M": rates in a line that stays short.
std::string compact(double v) {
  if (v >= 1e6) return fmt::format("{:.1f}M", v / 1e6);
  if (v >= 1e4) return fmt::format("{:.0f}k", v / 1e3);
  if (v >= 1e3) return fmt::format("{:.1f}k", v / 1e3);
  return fmt::format("{:.0f}", v);
}

// Rates in JSON: one decimal, a stable text for golden tests.
std::string rate(double v) {
  return fmt::format("{:.1f}", v);
}

std::string bus_label(const BusStatistics& b) {
  return b.module != 0 ? fmt::format("module {} bus {}", b.module, b.interface)
                       : fmt::format("bus {}", b.interface);
}

// Prometheus label values escape backslash, double quote and line feed.
std::string label_value(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '\\' || c == '"') {
      out += '\\';
      out += c;
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out += c;
    }
  }
  return out;
}

class Exposition {
 public:
  // Writes HELP and TYPE once per metric family, in the order families first appear.
  void family(const char* name, const char* type, const char* help) {
    out_ += fmt::format("# HELP {} {}\n# TYPE {} {}\n", name, help, name, type);
  }
  void sample(const char* name, const std::string& labels, std::uint64_t value) {
    out_ += labels.empty() ? fmt::format("{} {}\n", name, value)
                           : fmt::format("{}{{{}}} {}\n", name, labels, value);
  }
  void sample(const char* name, const std::string& labels, double value) {
    out_ += labels.empty() ? fmt::format("{} {}\n", name, value)
                           : fmt::format("{}{{{}}} {}\n", name, labels, value);
  }
  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

std::string bus_labels(const BusStatistics& b) {
  return fmt::format("module=\"{}\",bus=\"{}\"", b.module, label_value(b.interface));
}

}  // namespace

std::string json_string(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (u < 0x20) {
      out += fmt::format("\\u{:04x}", u);
    } else {
      out += c;
    }
  }
  return out + "\"";
}

std::string bus_state_name(const BusStatistics& bus) {
  return bus.link_up ? can::to_string(bus.counters.state) : "down";
}

std::string statistics_line(const RoleStatistics& s, const RoleRates& r) {
  const BackboneStatistics& b = s.backbone;
  std::string line = fmt::format("{} {}: ", s.role, s.name);
  if (s.role == "surface") {
    line += fmt::format("{}/{} gateway(s) up", b.peers_up, b.peers_known);
  } else {
    line += b.peers_up != 0 ? "link up" : "link down";
  }
  if (b.round_trip) line += fmt::format(" rtt {:.1f} ms", b.round_trip->count() / 1000.0);
  // The three busiest buses, then every other one that is not up and error-active.
  std::vector<std::size_t> order(s.buses.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  auto load = [&](std::size_t i) {
    return i < r.buses.size() ? r.buses[i].rx_frames + r.buses[i].tx_frames : 0.0;
  };
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t x, std::size_t y) { return load(x) > load(y); });
  std::size_t shown = 0;
  for (std::size_t i : order) {
    const BusStatistics& bus = s.buses[i];
    const bool healthy = bus.link_up && bus.counters.state == can::BusState::error_active;
    if (shown >= 3 && healthy) continue;
    ++shown;
    line += fmt::format("; {} {}", bus_label(bus), bus_state_name(bus));
    if (i < r.buses.size()) {
      line += fmt::format(" rx {}/s tx {}/s", compact(r.buses[i].rx_frames),
                          compact(r.buses[i].tx_frames));
    }
  }
  if (shown < s.buses.size()) line += fmt::format("; {} more bus(es)", s.buses.size() - shown);
  line += fmt::format("; backbone out {}B/s {} frames/s", compact(r.backbone_tx_bytes),
                      compact(r.backbone_frames_sent));
  if (r.frames_per_message > 0) line += fmt::format(" ({:.1f}/msg)", r.frames_per_message);
  line += fmt::format(", in {}B/s {} frames/s", compact(r.backbone_rx_bytes),
                      compact(r.backbone_frames_received));
  line += fmt::format(", resent {}", b.reliable_resent);
  // Drops: the total, then the two largest reasons.
  line += fmt::format("; drops {}", s.drops_total());
  std::vector<const DropCount*> nonzero;
  for (const DropCount& d : s.drops) {
    if (d.count != 0) nonzero.push_back(&d);
  }
  std::stable_sort(nonzero.begin(), nonzero.end(),
                   [](const DropCount* x, const DropCount* y) { return x->count > y->count; });
  if (!nonzero.empty()) {
    line += " (";
    for (std::size_t i = 0; i < nonzero.size() && i < 2; ++i) {
      line += fmt::format("{}{} {}", i == 0 ? "" : ", ", nonzero[i]->reason, nonzero[i]->count);
    }
    if (nonzero.size() > 2) line += ", ...";
    line += ")";
  }
  const NodeSummary& n = s.nodes;
  line += fmt::format("; nodes {} ({} op, {} lost)", n.total(), n.operational, n.lost);
  return line;
}

std::string statistics_json(const RoleStatistics& s, const RoleRates& r) {
  std::string j = fmt::format("{{\"role\":{},\"name\":{},\"window_s\":{:.3f},\"buses\":[",
                              json_string(s.role), json_string(s.name), r.seconds);
  for (std::size_t i = 0; i < s.buses.size(); ++i) {
    const BusStatistics& b = s.buses[i];
    const can::BusCounters& c = b.counters;
    const BusRates rates = i < r.buses.size() ? r.buses[i] : BusRates{};
    j += fmt::format(
        "{}{{\"module\":{},\"interface\":{},\"state\":\"{}\",\"link_up\":{},"
        "\"fault_state\":\"{}\",\"rx_frames\":{},\"tx_frames\":{},\"rx_frames_per_s\":{},"
        "\"tx_frames_per_s\":{},\"rx_dropped_kernel\":{},\"rx_dropped_queue\":{},"
        "\"tx_dropped_queue\":{},\"tx_dropped_error\":{},\"tx_dropped_interface_lost\":{},"
        "\"rx_dropped_interface_lost\":{},\"tx_retries\":{},\"error_frames\":{},\"reopens\":{}}}",
        i == 0 ? "" : ",", b.module, json_string(b.interface), bus_state_name(b),
        b.link_up ? "true" : "false", can::to_string(c.state), c.rx_frames, c.tx_frames,
        rate(rates.rx_frames), rate(rates.tx_frames), c.rx_dropped_kernel, c.rx_dropped_queue,
        c.tx_dropped_queue, c.tx_dropped_error, c.tx_dropped_interface_lost,
        c.rx_dropped_interface_lost, c.tx_retries, c.error_frames, c.reopens);
  }
  const BackboneStatistics& b = s.backbone;
  j += fmt::format(
      "],\"backbone\":{{\"peers_up\":{},\"peers_known\":{},\"links\":{},\"dead_links\":{},"
      "\"tx_bytes\":{},\"rx_bytes\":{},\"tx_bytes_per_s\":{},\"rx_bytes_per_s\":{},"
      "\"tx_writes\":{},\"rx_messages\":{},\"frames_sent\":{},\"frames_received\":{},"
      "\"frames_sent_per_s\":{},\"frames_received_per_s\":{},\"frames_per_message\":{},"
      "\"batches_sent\":{},\"reliable_sent\":{},\"reliable_resent\":{},\"resend_requests\":{},"
      "\"unacked\":{},\"round_trip_ms\":{}}}",
      b.peers_up, b.peers_known, b.links, b.dead_links, b.tx_bytes, b.rx_bytes,
      rate(r.backbone_tx_bytes), rate(r.backbone_rx_bytes), b.tx_writes, b.rx_messages,
      b.frames_sent, b.frames_received, rate(r.backbone_frames_sent),
      rate(r.backbone_frames_received), rate(r.frames_per_message), b.batches_sent, b.reliable_sent,
      b.reliable_resent, b.resend_requests, b.unacked,
      b.round_trip ? fmt::format("{:.3f}", b.round_trip->count() / 1000.0) : "null");
  j += fmt::format(",\"drops\":{{\"total\":{},\"per_s\":{},\"by_reason\":{{", s.drops_total(),
                   rate(r.drops));
  for (std::size_t i = 0; i < s.drops.size(); ++i) {
    j +=
        fmt::format("{}{}:{}", i == 0 ? "" : ",", json_string(s.drops[i].reason), s.drops[i].count);
  }
  j += "}}";
  if (!s.sdo_requests.empty()) {
    j += ",\"sdo_requests\":{";
    for (std::size_t i = 0; i < s.sdo_requests.size(); ++i) {
      j += fmt::format("{}{}:{}", i == 0 ? "" : ",", json_string(s.sdo_requests[i].outcome),
                       s.sdo_requests[i].count);
    }
    j += "}";
  }
  const NodeSummary& n = s.nodes;
  j += fmt::format(
      ",\"nodes\":{{\"total\":{},\"operational\":{},\"pre_operational\":{},\"stopped\":{},"
      "\"in_loader\":{},\"lost\":{},\"unknown\":{}}}}}",
      n.total(), n.operational, n.pre_operational, n.stopped, n.in_loader, n.lost, n.unknown);
  return j;
}

std::string statistics_prometheus(const RoleStatistics& s) {
  Exposition e;
  e.family("canbridge_bus_frames_total", "counter", "CAN frames read (rx) and written (tx)");
  for (const BusStatistics& b : s.buses) {
    e.sample("canbridge_bus_frames_total", bus_labels(b) + ",direction=\"rx\"",
             b.counters.rx_frames);
    e.sample("canbridge_bus_frames_total", bus_labels(b) + ",direction=\"tx\"",
             b.counters.tx_frames);
  }
  e.family("canbridge_bus_dropped_frames_total", "counter", "CAN frames lost on a bus, by reason");
  for (const BusStatistics& b : s.buses) {
    const can::BusCounters& c = b.counters;
    const std::string l = bus_labels(b);
    e.sample("canbridge_bus_dropped_frames_total", l + ",direction=\"rx\",reason=\"kernel\"",
             c.rx_dropped_kernel);
    e.sample("canbridge_bus_dropped_frames_total", l + ",direction=\"rx\",reason=\"queue\"",
             c.rx_dropped_queue);
    e.sample("canbridge_bus_dropped_frames_total",
             l + ",direction=\"rx\",reason=\"interface-lost\"", c.rx_dropped_interface_lost);
    e.sample("canbridge_bus_dropped_frames_total", l + ",direction=\"tx\",reason=\"queue\"",
             c.tx_dropped_queue);
    e.sample("canbridge_bus_dropped_frames_total", l + ",direction=\"tx\",reason=\"error\"",
             c.tx_dropped_error);
    e.sample("canbridge_bus_dropped_frames_total",
             l + ",direction=\"tx\",reason=\"interface-lost\"", c.tx_dropped_interface_lost);
  }
  e.family("canbridge_bus_tx_retries_total", "counter", "transmit back-offs (EAGAIN, ENOBUFS)");
  for (const BusStatistics& b : s.buses) {
    e.sample("canbridge_bus_tx_retries_total", bus_labels(b), b.counters.tx_retries);
  }
  e.family("canbridge_bus_error_frames_total", "counter", "CAN error frames received");
  for (const BusStatistics& b : s.buses) {
    e.sample("canbridge_bus_error_frames_total", bus_labels(b), b.counters.error_frames);
  }
  e.family("canbridge_bus_reopens_total", "counter", "times the interface was lost and reopened");
  for (const BusStatistics& b : s.buses) {
    e.sample("canbridge_bus_reopens_total", bus_labels(b), b.counters.reopens);
  }
  e.family("canbridge_bus_up", "gauge", "1 while the CAN interface is up");
  for (const BusStatistics& b : s.buses) {
    e.sample("canbridge_bus_up", bus_labels(b), std::uint64_t{b.link_up ? 1U : 0U});
  }
  e.family("canbridge_bus_state", "gauge", "1 for the bus's fault-confinement state");
  for (const BusStatistics& b : s.buses) {
    for (can::BusState state : kBusStates) {
      e.sample("canbridge_bus_state",
               bus_labels(b) + fmt::format(",state=\"{}\"", can::to_string(state)),
               std::uint64_t{b.counters.state == state ? 1U : 0U});
    }
  }
  const BackboneStatistics& k = s.backbone;
  e.family("canbridge_backbone_peers_up", "gauge", "backbone peers linked now");
  e.sample("canbridge_backbone_peers_up", "", std::uint64_t{k.peers_up});
  e.family("canbridge_backbone_links_total", "counter", "backbone links established");
  e.sample("canbridge_backbone_links_total", "", k.links);
  e.family("canbridge_backbone_dead_links_total", "counter", "links closed as dead");
  e.sample("canbridge_backbone_dead_links_total", "", k.dead_links);
  e.family("canbridge_backbone_bytes_total", "counter", "bytes on backbone links");
  e.sample("canbridge_backbone_bytes_total", "direction=\"rx\"", k.rx_bytes);
  e.sample("canbridge_backbone_bytes_total", "direction=\"tx\"", k.tx_bytes);
  e.family("canbridge_backbone_messages_total", "counter", "backbone messages read");
  e.sample("canbridge_backbone_messages_total", "direction=\"rx\"", k.rx_messages);
  e.family("canbridge_backbone_writes_total", "counter", "backbone link writes");
  e.sample("canbridge_backbone_writes_total", "", k.tx_writes);
  e.family("canbridge_backbone_batches_total", "counter", "frame batches sent");
  e.sample("canbridge_backbone_batches_total", "", k.batches_sent);
  e.family("canbridge_backbone_frames_total", "counter", "CAN frames carried on the backbone");
  e.sample("canbridge_backbone_frames_total", "direction=\"rx\"", k.frames_received);
  e.sample("canbridge_backbone_frames_total", "direction=\"tx\"", k.frames_sent);
  e.family("canbridge_backbone_reliable_sent_total", "counter", "reliable payloads, first sends");
  e.sample("canbridge_backbone_reliable_sent_total", "", k.reliable_sent);
  e.family("canbridge_backbone_reliable_resent_total", "counter", "reliable payloads resent");
  e.sample("canbridge_backbone_reliable_resent_total", "", k.reliable_resent);
  e.family("canbridge_backbone_resend_requests_total", "counter", "gaps seen in the peer's stream");
  e.sample("canbridge_backbone_resend_requests_total", "", k.resend_requests);
  e.family("canbridge_backbone_unacked", "gauge", "reliable payloads awaiting acknowledgement");
  e.sample("canbridge_backbone_unacked", "", k.unacked);
  if (k.round_trip) {
    e.family("canbridge_backbone_round_trip_seconds", "gauge",
             "smoothed reliable payload round trip");
    e.sample("canbridge_backbone_round_trip_seconds", "",
             static_cast<double>(k.round_trip->count()) / 1e6);
  }
  e.family("canbridge_dropped_frames_total", "counter",
           "frames the role did not forward, by reason");
  for (const DropCount& d : s.drops) {
    e.sample("canbridge_dropped_frames_total", fmt::format("reason=\"{}\"", label_value(d.reason)),
             d.count);
  }
  if (!s.sdo_requests.empty()) {
    e.family("canbridge_sdo_requests_total", "counter",
             "surface masters' SDO requests across link cuts, by outcome");
    for (const SdoOutcomeCount& o : s.sdo_requests) {
      e.sample("canbridge_sdo_requests_total",
               fmt::format("outcome=\"{}\"", label_value(o.outcome)), o.count);
    }
  }
  e.family("canbridge_nodes", "gauge", "nodes in the node table by state");
  const NodeSummary& n = s.nodes;
  e.sample("canbridge_nodes", "state=\"operational\"", n.operational);
  e.sample("canbridge_nodes", "state=\"pre-operational\"", n.pre_operational);
  e.sample("canbridge_nodes", "state=\"stopped\"", n.stopped);
  e.sample("canbridge_nodes", "state=\"loader\"", n.in_loader);
  e.sample("canbridge_nodes", "state=\"lost\"", n.lost);
  e.sample("canbridge_nodes", "state=\"unknown\"", n.unknown);
  return e.take();
}

}  // namespace canbridge::bridge
