#include "config/loader.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "canopen/pdop.hpp"
#include "config/backbone_auth_reader.hpp"
#include "config/remote_access_reader.hpp"
#include "routing/node_map.hpp"
#include "yaml/yaml_reader.hpp"

namespace canbridge::config {

namespace {

constexpr std::size_t kMaxStatsSocketPath = 107;  // sun_path less its terminating NUL

// The shared reader plus the value kinds only role configs have.
class Reader : public YamlReader {
 public:
  using YamlReader::YamlReader;

  std::optional<Endpoint> endpoint(const YAML::Node& map, const char* key, const std::string& path,
                                   bool required) {
    auto text = string(map, key, path, required);
    if (!text) return std::nullopt;
    const auto colon = text->rfind(':');
    Endpoint ep;
    unsigned port = 0;
    if (colon == std::string::npos || colon == 0) {
      problem(map[key], join_path(path, key), "'" + *text + "' must be host:port");
      return std::nullopt;
    }
    ep.host = text->substr(0, colon);
    const std::string port_text = text->substr(colon + 1);
    auto [ptr, ec] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
    if (ec != std::errc{} || ptr != port_text.data() + port_text.size() || port > 65535) {
      problem(map[key], join_path(path, key), "port '" + port_text + "' must be 0..65535");
      return std::nullopt;
    }
    ep.port = static_cast<std::uint16_t>(port);
    return ep;
  }

  // A line of a serial backbone: {device, baud, flow_control}, and on the surface the gateway it
  // serves (read with the surface's auth, which decides whether it is required).
  std::optional<SerialLineOptions> serial_line(const YAML::Node& node, const std::string& path,
                                               bool surface) {
    if (!node.IsMap()) {
      problem(node, path, "must be a mapping with device, baud and flow_control");
      return std::nullopt;
    }
    if (surface) {
      only_keys(node, path, {"device", "baud", "flow_control", "gateway"});
    } else {
      only_keys(node, path, {"device", "baud", "flow_control"});
    }
    SerialLineOptions line;
    bool ok = true;
    if (auto device = file_path(node, "device", path, true)) {
      line.device = *device;
    } else {
      ok = false;
    }
    if (const YAML::Node baud = node["baud"]) {
      if (auto rate = baud_rate(baud, join_path(path, "baud"))) {
        line.baud = *rate;
      } else {
        ok = false;
      }
    }
    if (auto flow = string(node, "flow_control", path, false)) {
      if (*flow == "hardware") {
        line.hardware_flow_control = true;
      } else if (*flow != "none") {
        // XON/XOFF is not offered: it would swallow those byte values out of the binary frames.
        problem(node["flow_control"], join_path(path, "flow_control"),
                "'" + *flow + "' is not one of none, hardware (RTS/CTS)");
        ok = false;
      }
    } else if (node["flow_control"]) {
      ok = false;
    }
    if (!ok) return std::nullopt;
    return line;
  }

  // Only the rates termios has a B constant for: any other rate would fail when the line opens,
  // long after startup, so it is refused here.
  std::optional<unsigned> baud_rate(const YAML::Node& node, const std::string& field) {
    static constexpr std::array<unsigned, 19> kRates = {
        1200,   2400,   4800,   9600,    19200,   38400,   57600,   115200,  230400, 460800,
        500000, 576000, 921600, 1000000, 1152000, 1500000, 2000000, 3000000, 4000000};
    auto v = integer_text(node, field);
    if (!v) return std::nullopt;
    if (!v->negative && !v->overflow &&
        std::find(kRates.begin(), kRates.end(), v->magnitude) != kRates.end()) {
      return static_cast<unsigned>(v->magnitude);
    }
    problem(node, field,
            node.Scalar() +
                " is not a standard serial rate (e.g. 9600, 19200, 57600, 115200, 230400, 460800, "
                "921600, 1000000; up to 4000000)");
    return std::nullopt;
  }

  // The session keys both roles share under `backbone`.
  void session_tuning(const YAML::Node& backbone, SessionTuning& out) {
    read_liveness(backbone, out);
    read_retransmission(backbone, out);
    // Buffer and queue sizes: plain counts, each with its own sane range.
    struct Count {
      const char* key;
      std::int64_t min;
      std::int64_t max;
      std::size_t SessionTuning::*field;
    };
    static constexpr Count kCounts[] = {
        {"resend_buffer_messages", 1, 1LL << 20, &SessionTuning::resend_buffer_messages},
        {"resend_buffer_bytes", 1024, 1LL << 30, &SessionTuning::resend_buffer_bytes},
        {"max_write_bytes", 64, 1LL << 20, &SessionTuning::max_write_bytes},
        {"queue_reliable_frames", 1, 1LL << 22, &SessionTuning::queue_reliable_frames},
        {"queue_process_frames", 1, 1LL << 22, &SessionTuning::queue_process_frames},
    };
    for (const Count& c : kCounts) {
      if (auto v = integer(backbone, c.key, "backbone", c.min, c.max, false)) {
        out.*c.field = static_cast<std::size_t>(*v);
      }
    }
    if (auto after = backbone_ms(backbone, "conflate_after_ms", 0, 60000)) {
      out.conflate_after = *after;
    }
    read_tcp_framing(backbone, out);
  }

  std::optional<std::chrono::milliseconds> backbone_ms(const YAML::Node& backbone, const char* key,
                                                       std::int64_t min, std::int64_t max) {
    auto v = integer(backbone, key, "backbone", min, max, false);
    return v ? std::optional<std::chrono::milliseconds>(*v) : std::nullopt;
  }

  void read_liveness(const YAML::Node& backbone, SessionTuning& out) {
    const auto keepalive = backbone_ms(backbone, "keepalive_ms", 10, 600000);
    const auto dead_after = backbone_ms(backbone, "dead_after_ms", 10, 3600000);
    if (keepalive) out.keepalive = *keepalive;
    if (dead_after) out.dead_after = *dead_after;
    // A link must not be declared dead while the peer is merely between two keepalives. Checked
    // only when neither value is already reported, and against the default when one is absent.
    const bool keepalive_ok = keepalive || !backbone["keepalive_ms"];
    const bool dead_after_ok = dead_after || !backbone["dead_after_ms"];
    if (!keepalive_ok || !dead_after_ok || out.dead_after > out.keepalive) return;
    const std::string ka = std::to_string(out.keepalive.count());
    const std::string da = std::to_string(out.dead_after.count());
    if (dead_after) {
      problem(backbone["dead_after_ms"], "backbone.dead_after_ms",
              da + " must exceed keepalive_ms (" + ka + "), best by a few keepalives");
    } else {
      problem(backbone["keepalive_ms"], "backbone.dead_after_ms",
              "the default " + da + " does not exceed keepalive_ms (" + ka +
                  "): give dead_after_ms, a few keepalives longer");
    }
  }

  // A frame lost once must still be young enough to be resent. Checked like dead_after_ms.
  void read_retransmission(const YAML::Node& backbone, SessionTuning& out) {
    const auto retransmit = backbone_ms(backbone, "retransmit_ms", 10, 600000);
    if (retransmit) out.retransmit = *retransmit;
    const auto max_age = backbone_ms(backbone, "reliable_max_age_ms", 100, 3600000);
    if (max_age) out.reliable_max_age = *max_age;
    const bool max_age_ok = max_age || !backbone["reliable_max_age_ms"];
    const bool retransmit_ok = retransmit || !backbone["retransmit_ms"];
    if (!max_age_ok || !retransmit_ok || out.reliable_max_age > out.retransmit) return;
    const std::string age = std::to_string(out.reliable_max_age.count());
    const std::string rto = std::to_string(out.retransmit.count());
    if (max_age) {
      problem(backbone["reliable_max_age_ms"], "backbone.reliable_max_age_ms",
              age + " must exceed retransmit_ms (" + rto +
                  "), or a frame lost once could never be resent");
    } else {
      problem(backbone["retransmit_ms"], "backbone.reliable_max_age_ms",
              "the default " + age + " does not exceed retransmit_ms (" + rto +
                  "): give reliable_max_age_ms, longer than retransmit_ms");
    }
  }

  void read_tcp_framing(const YAML::Node& backbone, SessionTuning& out) {
    auto framing = string(backbone, "tcp_framing", "backbone", false);
    if (!framing) return;
    if (*framing == "length-prefix") {
      out.tcp_crc_framing = false;
    } else if (*framing == "cobs-crc32c") {
      out.tcp_crc_framing = true;
    } else {
      problem(backbone["tcp_framing"], "backbone.tcp_framing",
              "'" + *framing + "' is not one of length-prefix, cobs-crc32c");
    }
  }

  void can_options(const YAML::Node& root, CanOptions& out) {
    const YAML::Node can = root["can"];
    if (!can) return;
    if (!can.IsMap()) return problem(can, "can", "must be a mapping");
    only_keys(can, "can", {"receive_buffer_bytes", "transmit_queue_frames"});
    if (auto v = integer(can, "receive_buffer_bytes", "can", 64 * 1024, 1LL << 30, false)) {
      out.receive_buffer_bytes = static_cast<std::size_t>(*v);
    }
    if (auto v = integer(can, "transmit_queue_frames", "can", 16, 1 << 20, false)) {
      out.transmit_queue_frames = static_cast<std::size_t>(*v);
    }
  }

  // `metrics: {listen: HOST:PORT}`: the Prometheus endpoint, on loopback only (it has no
  // authentication; reach it from elsewhere through a scraper on the machine or ssh).
  void metrics_options(const YAML::Node& root, std::optional<MetricsOptions>& out) {
    const YAML::Node block = root["metrics"];
    if (!block) return;
    if (!block.IsMap())
      return problem(block, "metrics", "must be a mapping, e.g. {listen: 127.0.0.1:9464}");
    only_keys(block, "metrics", {"listen"});
    auto ep = endpoint(block, "listen", "metrics", true);
    if (!ep) return;
    if (!is_loopback_host(ep->host)) {
      return problem(block["listen"], "metrics.listen",
                     "'" + ep->host +
                         "' is not a loopback address (127.0.0.0/8, ::1, localhost): the metrics "
                         "endpoint has no authentication");
    }
    if (ep->host == "localhost") ep->host = "127.0.0.1";
    if (ep->host.size() > 2 && ep->host.front() == '[' && ep->host.back() == ']') {
      ep->host = ep->host.substr(1, ep->host.size() - 2);  // [::1]:9464
    }
    out = MetricsOptions{*ep};
  }

  void log_options(const YAML::Node& root, LogOptions& out) {
    const YAML::Node log = root["log"];
    if (!log) return;
    if (!log.IsMap()) return problem(log, "log", "must be a mapping");
    only_keys(log, "log", {"level", "stats_interval_s"});
    if (auto level = string(log, "level", "log", false)) {
      static const std::set<std::string> levels = {"trace", "debug", "info",
                                                   "warn",  "error", "off"};
      if (levels.count(*level) == 0) {
        problem(log["level"], "log.level",
                "'" + *level + "' is not one of trace, debug, info, warn, error, off");
      } else {
        out.level = *level;
      }
    }
    if (auto v = integer(log, "stats_interval_s", "log", 0, 86400, false)) {
      out.stats_interval = std::chrono::seconds(*v);
    }
  }
};

YAML::Node parse_root(std::string_view yaml, const std::string& file, const char* role) {
  const YAML::Node root = parse_document(yaml, file);
  const YAML::Node r = root["role"];
  if (!r || !r.IsScalar() || r.Scalar() != role) {
    const int line = r && r.Mark().line >= 0 ? r.Mark().line + 1 : 0;
    throw ConfigError(
        {{file, line, "role", std::string("must be '") + role + "' for this command"}});
  }
  return root;
}

// The key node of `key` in `map` (its line is where an operator looks); an undefined node (false,
// line 0) if absent. YAML::Node() would not do: it is a defined null node.
YAML::Node key_of(const YAML::Node& map, std::string_view key) {
  for (const auto& kv : map) {
    if (kv.first.Scalar() == key) return kv.first;
  }
  return YAML::Node(YAML::NodeType::Undefined);
}

// A validator of a bridge unit says "field: message" in the unit's names; the file names
// durations with their unit (fragment_timeout -> fragment_timeout_ms).
std::string yaml_key(const std::string& unit_field) {
  constexpr std::string_view kTimeout = "_timeout";
  const bool duration =
      unit_field.size() >= kTimeout.size() &&
      unit_field.compare(unit_field.size() - kTimeout.size(), kTimeout.size(), kTimeout) == 0;
  return duration ? unit_field + "_ms" : unit_field;
}

// Reports the problems a unit's own validator finds in options read from `block` (`path`), each
// once (the reassembler and the segmenter both check max_packet_bytes), at the key it names, or at
// the block's key when the value is a default. The loader's range checks come first; what is left
// for the validators is what ties fields together (max_held_bytes against max_packet_bytes), and
// running them keeps the loader from accepting what the unit would throw on at startup.
void report_unit_problems(Reader& in, const std::vector<std::string>& problems,
                          const YAML::Node& block, const YAML::Node& block_key,
                          const std::string& path, std::set<std::string>& reported) {
  for (const std::string& p : problems) {
    const auto colon = p.find(": ");
    const std::string key =
        colon == std::string::npos ? std::string() : yaml_key(p.substr(0, colon));
    const std::string message = colon == std::string::npos ? p : p.substr(colon + 2);
    const std::string field = key.empty() ? path : path + "." + key;
    if (!reported.insert(field).second) continue;
    const YAML::Node value = key.empty() ? YAML::Node(YAML::NodeType::Undefined) : block[key];
    in.problem(value ? line_of(value) : line_of(block_key), field, message);
  }
}

// A module's `pdop:` block (docs/pdop.md section 5): whether TPDOP packets cross whole, and the
// gateway's reassembler and segmenter limits. Only a pdop module has PDO Packets; on another
// profile the block is refused but still checked, so that one pass shows every problem.
void read_module_pdop(Reader& in, const YAML::Node& m, const std::string& path, bool profile_ok,
                      ModuleOptions& module) {
  const YAML::Node key = key_of(m, "pdop");
  if (!key) return;
  const std::string field = path + ".pdop";
  if (profile_ok && module.profile != bridge::IdProfile::pdop) {
    in.problem(key, field,
               std::string("applies to pdop modules only (this module's profile is ") +
                   bridge::to_string(module.profile) + "): only they send PDO Packets");
  }
  const YAML::Node block = m["pdop"];
  if (!block.IsMap()) {
    // At the key: an empty value ("pdop:") has no line of its own.
    return in.problem(key, field,
                      "must be a mapping, e.g. {max_packet_bytes: 4096, window: 4} ({} for the "
                      "defaults)");
  }
  in.only_keys(block, field,
               {"reassemble", "max_packet_bytes", "fragment_timeout_ms", "window", "ack_timeout_ms",
                "retries", "queue_per_rpdo", "max_held_bytes"});
  const std::size_t before = in.problems().size();
  using std::chrono::milliseconds;
  auto& reassembly = module.pdop_reassembly;
  auto& segmentation = module.pdop_segmentation;
  if (auto v = in.boolean(block, "reassemble", field)) module.reassemble_pdop = *v;
  if (auto v = in.integer(block, "max_packet_bytes", field, 1,
                          static_cast<std::int64_t>(canopen::pdop::kMaxPacketBytes))) {
    reassembly.max_packet_bytes = static_cast<std::size_t>(*v);
    segmentation.max_packet_bytes = static_cast<std::size_t>(*v);
  }
  if (auto v = in.integer(block, "fragment_timeout_ms", field, 1, 10000)) {
    reassembly.fragment_timeout = milliseconds(*v);
  }
  if (auto v = in.integer(block, "window", field, 1, 255)) {
    segmentation.window = static_cast<std::uint8_t>(*v);
  }
  if (auto v = in.integer(block, "ack_timeout_ms", field, 1, 10000)) {
    segmentation.ack_timeout = milliseconds(*v);
  }
  if (auto v = in.integer(block, "retries", field, 0, 10)) {
    segmentation.retries = static_cast<unsigned>(*v);
  }
  if (auto v = in.integer(block, "queue_per_rpdo", field, 0, 1024)) {
    segmentation.queue_per_rpdo = static_cast<std::size_t>(*v);
  }
  if (auto v = in.integer(block, "max_held_bytes", field, 1, std::int64_t{1} << 30)) {
    segmentation.max_held_bytes = static_cast<std::size_t>(*v);
  }
  // With a value already refused (and left at its default), a cross check would judge the
  // default, not what the operator wrote.
  if (in.problems().size() != before) return;
  std::set<std::string> reported;
  if (auto p = reassembly.validate()) report_unit_problems(in, {*p}, block, key, field, reported);
  report_unit_problems(in, bridge::validate(segmentation), block, key, field, reported);
}

// False when a profile is given but refused, so checks that depend on it stay quiet.
bool read_module_profile(Reader& in, const YAML::Node& m, const std::string& path,
                         ModuleOptions& module) {
  auto profile = in.string(m, "profile", path, false);
  if (!profile) return !m["profile"];
  if (auto p = bridge::parse_id_profile(*profile)) {
    module.profile = *p;
    return true;
  }
  in.problem(m["profile"], path + ".profile", "'" + *profile + "' is not one of cia301, pdop, qd");
  return false;
}

// One bus per module (that it is an interface name the kernel takes is checked as it is read).
void check_module_bus(Reader& in, const YAML::Node& m, const std::string& path,
                      const std::string& bus, std::set<std::string>& buses) {
  if (!buses.insert(bus).second) {
    in.problem(m["bus"], path + ".bus", "bus '" + bus + "' is used by two modules");
  }
}

// `nodes: {local: surface, ...}`, or the default map when absent (only for low module ids);
// false when the map is refused.
bool read_module_nodes(Reader& in, const YAML::Node& m, const std::string& path,
                       std::optional<std::int64_t> id, ModuleOptions& module) {
  const YAML::Node nodes = m["nodes"];
  if (!nodes) {
    if (!id || *id <= bridge::kMaxDefaultModuleId) return true;
    in.problem(m["id"], path + ".id",
               "modules above " + std::to_string(bridge::kMaxDefaultModuleId) +
                   " have no default node map (local + 32 x id would pass 127): give 'nodes'");
    return false;
  }
  module.default_nodes = false;
  if (!nodes.IsMap() || nodes.size() == 0) {
    in.problem(nodes, path + ".nodes", "must map local node ids to surface node ids, e.g. {1: 33}");
    return false;
  }
  bool ok = true;
  for (const auto& kv : nodes) {
    const std::string field = path + ".nodes." + kv.first.Scalar();
    auto local = in.integer(kv.first, field, 1, 127);
    auto surface = in.integer(kv.second, field, 1, 127);
    if (local && surface) {
      module.nodes.emplace_back(static_cast<std::uint8_t>(*local),
                                static_cast<std::uint8_t>(*surface));
    } else {
      ok = false;
    }
  }
  return ok;
}

// Every field of the module is read even after a problem, so one pass reports them all; the
// module is returned when it has an id and a bus.
std::optional<ModuleOptions> read_module(Reader& in, const YAML::Node& m, const std::string& path,
                                         std::set<std::string>& buses, bridge::NodeMap& map) {
  in.only_keys(
      m, path,
      {"id", "bus", "nodes", "conflate_pdos", "profile", "heartbeat_lost_ms", "census", "pdop"});
  ModuleOptions module;
  auto id = in.integer(m, "id", path, 0, 0xFFFFFFFELL, true);
  auto bus = in.interface_name(m, "bus", path, true);
  const bool profile_ok = read_module_profile(in, m, path, module);
  if (auto conflate = in.boolean(m, "conflate_pdos", path)) module.conflate_pdos = *conflate;
  if (auto census = in.boolean(m, "census", path)) module.census = *census;
  if (auto lost = in.integer(m, "heartbeat_lost_ms", path, 10, 600000, false)) {
    module.heartbeat_lost_after = std::chrono::milliseconds(*lost);
  }
  read_module_pdop(in, m, path, profile_ok, module);
  if (bus) check_module_bus(in, m, path, *bus, buses);
  bool nodes_ok = read_module_nodes(in, m, path, id, module);
  if (!id || !bus) return std::nullopt;
  module.id = static_cast<std::uint32_t>(*id);
  module.bus = *bus;
  if (module.default_nodes) module.nodes = bridge::NodeMap::default_pairs(module.id);
  if (nodes_ok && profile_ok && module.default_nodes && module.id != 0 &&
      module.profile != bridge::IdProfile::cia301) {
    // One problem, not one per node: the default map of module 1.. starts at surface 33.
    in.problem(m["profile"], path + ".profile",
               std::string("a ") + bridge::to_string(module.profile) +
                   " module needs surface node ids 1..31 and the default map (local + 32 x " +
                   std::to_string(module.id) + ") leaves them: give 'nodes'");
    nodes_ok = false;
  }
  if (nodes_ok && profile_ok) {
    // Range and image problems are the node map's; without 'nodes' the profile line is where
    // the default map stopped fitting.
    const YAML::Node at = m["nodes"] ? m["nodes"] : m["profile"] ? m["profile"] : m;
    for (const std::string& p : map.add_module(module.id, module.nodes, module.profile)) {
      in.problem(at, path, p);
    }
  }
  return module;
}

void read_modules(Reader& in, const YAML::Node& root, GatewayOptions& out) {
  const YAML::Node modules = root["modules"];
  if (!modules) return in.problem(root, "modules", "missing (required): at least one module");
  if (!modules.IsSequence() || modules.size() == 0) {
    return in.problem(modules, "modules", "must be a non-empty list");
  }
  // Built alongside, so a module overlapping an earlier one is reported where it is written.
  bridge::NodeMap map;
  std::set<std::string> buses;
  for (std::size_t i = 0; i < modules.size(); ++i) {
    const YAML::Node m = modules[i];
    const std::string path = "modules[" + std::to_string(i) + "]";
    if (!m.IsMap()) {
      in.problem(m, path, "must be a mapping with id and bus");
      continue;
    }
    if (auto module = read_module(in, m, path, buses, map))
      out.modules.push_back(std::move(*module));
  }
}

// The surface's `pdop:` block: the limits of the relay that takes RPDOP packets from the surface
// master for pdop nodes behind gateways (routing/rpdop_relay.hpp).
void read_surface_pdop(Reader& in, const YAML::Node& root, bridge::RpdopRelayOptions& out) {
  const YAML::Node key = key_of(root, "pdop");
  if (!key) return;
  const YAML::Node block = root["pdop"];
  if (!block.IsMap()) {
    return in.problem(key, "pdop",
                      "must be a mapping, e.g. {max_packet_bytes: 4096, window: 4} ({} for the "
                      "defaults)");
  }
  in.only_keys(block, "pdop",
               {"max_packet_bytes", "fragment_timeout_ms", "window", "outcome_timeout_ms"});
  const std::size_t before = in.problems().size();
  using std::chrono::milliseconds;
  if (auto v = in.integer(block, "max_packet_bytes", "pdop", 1,
                          static_cast<std::int64_t>(canopen::pdop::kMaxPacketBytes))) {
    out.max_packet_bytes = static_cast<std::size_t>(*v);
  }
  if (auto v = in.integer(block, "fragment_timeout_ms", "pdop", 1, 10000)) {
    out.fragment_timeout = milliseconds(*v);
  }
  if (auto v = in.integer(block, "window", "pdop", 1, 255)) {
    out.window = static_cast<std::uint8_t>(*v);
  }
  if (auto v = in.integer(block, "outcome_timeout_ms", "pdop", 1, 600000)) {
    out.outcome_timeout = milliseconds(*v);
  }
  if (in.problems().size() != before) return;
  std::set<std::string> reported;
  report_unit_problems(in, bridge::validate(out), block, key, "pdop", reported);
}

}  // namespace

// Protobuf and envelope bytes around one PDO Packet's data, at most (ids, lengths, times).
constexpr std::size_t kPdopMessageOverhead = 128;

namespace {

// Exactly one transport: with both, which one the operator meant is anyone's guess.
void check_one_transport(Reader& in, const YAML::Node& root, const YAML::Node& backbone) {
  const YAML::Node connect_key = key_of(backbone, "connect");
  const YAML::Node serial_key = key_of(backbone, "serial");
  if (connect_key && serial_key) {
    const int connect_at = line_of(connect_key);
    const int serial_at = line_of(serial_key);
    in.problem(std::max(connect_at, serial_at), "backbone",
               "'connect' (line " + std::to_string(connect_at) + ") and 'serial' (line " +
                   std::to_string(serial_at) + ") are both given: a gateway uses exactly one");
  } else if (!connect_key && !serial_key) {
    in.problem(key_of(root, "backbone"), "backbone",
               "needs 'connect: host:port' (TCP) or 'serial:' (a serial line): neither is given");
  }
}

void read_gateway_link(Reader& in, const YAML::Node& backbone, GatewayOptions& out) {
  if (auto ep = in.endpoint(backbone, "connect", "backbone", false)) {
    if (ep->port == 0) {
      in.problem(backbone["connect"], "backbone.connect", "port 0 cannot be connected to");
    }
    out.connect = *ep;
  }
  if (const YAML::Node serial = backbone["serial"]) {
    if (serial.IsSequence()) {
      in.problem(serial, "backbone.serial",
                 "must be one mapping {device, baud, flow_control}: a gateway has one line");
    } else {
      out.serial = in.serial_line(serial, "backbone.serial", false);
    }
  }
  // Also the back-off of reopening a serial line that failed or went dead.
  if (auto v = in.integer(backbone, "reconnect_min_ms", "backbone", 1, 600000, false)) {
    out.reconnect_min = std::chrono::milliseconds(*v);
  }
  if (auto v = in.integer(backbone, "reconnect_max_ms", "backbone", 1, 600000, false)) {
    out.reconnect_max = std::chrono::milliseconds(*v);
  }
  if (out.reconnect_max < out.reconnect_min) {
    in.problem(backbone["reconnect_max_ms"], "backbone.reconnect_max_ms",
               "must not be below reconnect_min_ms");
  }
}

void read_gateway_backbone(Reader& in, const YAML::Node& root, GatewayOptions& out) {
  const YAML::Node backbone = root["backbone"];
  if (!backbone) {
    return in.problem(
        root, "backbone",
        "missing (required): needs 'connect: host:port' (TCP) or 'serial:' (a serial line)");
  }
  if (!backbone.IsMap()) {
    return in.problem(
        backbone, "backbone",
        "must be a mapping with 'connect: host:port' (TCP) or 'serial:' (a serial line)");
  }
  in.only_keys(backbone, "backbone",
               {"connect", "serial", "auth", "reconnect_min_ms", "reconnect_max_ms", "keepalive_ms",
                "dead_after_ms", "retransmit_ms", "reliable_max_age_ms", "resend_buffer_messages",
                "resend_buffer_bytes", "max_write_bytes", "queue_reliable_frames",
                "queue_process_frames", "conflate_after_ms", "tcp_framing"});
  check_one_transport(in, root, backbone);
  read_gateway_link(in, backbone, out);
  in.session_tuning(backbone, out.session);
}

// A packet crosses as one reliable message, which the resend buffer must be able to hold.
void check_packets_fit(Reader& in, const YAML::Node& root, const GatewayOptions& out) {
  for (std::size_t i = 0; i < out.modules.size(); ++i) {
    const ModuleOptions& m = out.modules[i];
    if (m.profile != bridge::IdProfile::pdop || !m.reassemble_pdop) continue;
    if (m.pdop_reassembly.max_packet_bytes + kPdopMessageOverhead <=
        out.session.resend_buffer_bytes) {
      continue;
    }
    const YAML::Node module = root["modules"][i];
    const YAML::Node at = module["pdop"] && module["pdop"]["max_packet_bytes"]
                              ? module["pdop"]["max_packet_bytes"]
                              : module;
    in.problem(at, "modules[" + std::to_string(i) + "].pdop.max_packet_bytes",
               std::to_string(m.pdop_reassembly.max_packet_bytes) +
                   " does not fit in backbone.resend_buffer_bytes (" +
                   std::to_string(out.session.resend_buffer_bytes) +
                   ") with its message: such a packet could never cross");
  }
}

// The one module whose bus the surface's LSS requests reach; it must be one of ours.
void read_lss_module(Reader& in, const YAML::Node& root, GatewayOptions& out) {
  auto lss = in.integer(root, "lss_module", "", 0, 0xFFFFFFFELL, false);
  if (!lss) return;
  const auto id = static_cast<std::uint32_t>(*lss);
  const bool served = std::any_of(out.modules.begin(), out.modules.end(),
                                  [&](const ModuleOptions& m) { return m.id == id; });
  if (!served) {
    in.problem(root["lss_module"], "lss_module",
               "module " + std::to_string(id) + " is not one of this gateway's modules");
  }
  out.lss_module = id;
}

// Two lines on one device would fight over its bytes: refused, naming both items.
void read_surface_lines(Reader& in, const YAML::Node& serial, SurfaceOptions& out) {
  std::map<std::string, std::size_t> devices;
  for (std::size_t i = 0; i < serial.size(); ++i) {
    const std::string path = item_path("backbone", "serial", i);
    auto line = in.serial_line(serial[i], path, true);
    // Checked on the device alone, so that it is reported even when another field is bad.
    const YAML::Node device = serial[i].IsMap() ? serial[i]["device"] : YAML::Node();
    if (device && device.IsScalar() && !device.Scalar().empty()) {
      if (auto [it, fresh] = devices.emplace(device.Scalar(), i); !fresh) {
        in.problem(device, path + ".device",
                   "'" + device.Scalar() + "' is also the device of backbone.serial[" +
                       std::to_string(it->second) + "]");
        continue;
      }
    }
    if (line) out.serial.push_back(std::move(*line));
  }
}

void read_surface_backbone(Reader& in, const YAML::Node& root, SurfaceOptions& out) {
  const YAML::Node backbone = root["backbone"];
  if (!backbone) {
    return in.problem(
        root, "backbone",
        "missing (required): needs 'listen: host:port' (TCP), 'serial:' lines, or both");
  }
  if (!backbone.IsMap()) {
    return in.problem(backbone, "backbone",
                      "must be a mapping with 'listen: host:port' (TCP), 'serial:' lines, or both");
  }
  in.only_keys(backbone, "backbone",
               {"listen", "serial", "auth", "admission", "conflate_pdos", "conflate_after_ms",
                "keepalive_ms", "dead_after_ms", "retransmit_ms", "reliable_max_age_ms",
                "resend_buffer_messages", "resend_buffer_bytes", "max_write_bytes",
                "queue_reliable_frames", "queue_process_frames", "tcp_framing"});
  // An empty list ("serial: []") reaches no gateway either.
  const YAML::Node lines = backbone["serial"];
  if (!key_of(backbone, "listen") && (!lines || (lines.IsSequence() && lines.size() == 0))) {
    in.problem(key_of(root, "backbone"), "backbone",
               "needs 'listen: host:port' (TCP), 'serial:' lines, or both: neither is given");
  }
  if (auto ep = in.endpoint(backbone, "listen", "backbone", false)) out.listen = *ep;
  if (lines && !lines.IsSequence()) {
    in.problem(lines, "backbone.serial",
               "must be a list of serial lines, one '- device: ...' item per gateway");
  } else if (lines) {
    read_surface_lines(in, lines, out);
  }
  if (auto conflate = in.boolean(backbone, "conflate_pdos", "backbone")) {
    out.conflate_pdos = *conflate;
  }
  in.session_tuning(backbone, out.session);
}

}  // namespace

GatewayOptions parse_gateway(std::string_view yaml, const std::string& file) {
  const YAML::Node root = parse_root(yaml, file, "gateway");
  Reader in(file);
  in.only_keys(root, "",
               {"role", "name", "backbone", "modules", "lss_module", "remote", "can", "log",
                "stats_endpoint", "metrics"});
  GatewayOptions out;
  if (auto name = in.string(root, "name", "", false)) out.name = *name;
  read_gateway_backbone(in, root, out);
  read_gateway_auth(in, root, out);
  read_modules(in, root, out);
  check_packets_fit(in, root, out);
  read_lss_module(in, root, out);
  read_gateway_remote(in, root, out.remote);
  in.can_options(root, out.can);
  in.log_options(root, out.log);
  if (auto socket = in.string(root, "stats_endpoint", "", false)) {
    if (socket->empty() || socket->front() != '/') {
      in.problem(root["stats_endpoint"], "stats_endpoint",
                 "'" + *socket + "' must be an absolute path (a Unix socket)");
    } else if (socket->size() > kMaxStatsSocketPath) {
      in.problem(root["stats_endpoint"], "stats_endpoint",
                 "longer than a Unix socket path may be (" + std::to_string(kMaxStatsSocketPath) +
                     " bytes)");
    } else {
      out.stats_endpoint = *socket;
    }
  }
  in.metrics_options(root, out.metrics);
  in.finish();
  return out;
}

SurfaceOptions parse_surface(std::string_view yaml, const std::string& file) {
  const YAML::Node root = parse_root(yaml, file, "surface");
  Reader in(file);
  in.only_keys(root, "",
               {"role", "name", "backbone", "gateways", "bus", "master_sdo_timeout_ms", "pdop",
                "command_endpoint", "networks", "can", "log", "metrics"});
  SurfaceOptions out;
  if (auto name = in.string(root, "name", "", false)) out.name = *name;
  if (auto bus = in.interface_name(root, "bus", "", true)) out.bus = *bus;
  if (auto t = in.integer(root, "master_sdo_timeout_ms", "", 10, 600000, false)) {
    out.master_sdo_timeout = std::chrono::milliseconds(*t);
  }
  read_surface_backbone(in, root, out);
  read_surface_auth(in, root, out);
  read_surface_pdop(in, root, out.rpdop_relay);
  read_surface_remote(in, root, out);
  // A packet crosses as one reliable message, which the resend buffer must be able to hold.
  if (out.rpdop_relay.max_packet_bytes + kPdopMessageOverhead > out.session.resend_buffer_bytes) {
    const YAML::Node pdop = root["pdop"];
    in.problem(pdop && pdop.IsMap() && pdop["max_packet_bytes"] ? pdop["max_packet_bytes"] : root,
               "pdop.max_packet_bytes",
               std::to_string(out.rpdop_relay.max_packet_bytes) +
                   " does not fit in backbone.resend_buffer_bytes (" +
                   std::to_string(out.session.resend_buffer_bytes) +
                   ") with its message: such a packet could never cross");
  }
  in.can_options(root, out.can);
  in.log_options(root, out.log);
  in.metrics_options(root, out.metrics);
  in.finish();
  return out;
}

std::string read_config_text(const std::string& path) {
  return read_config_file(path);
}

GatewayOptions load_gateway(const std::string& path) {
  return parse_gateway(read_config_file(path), path);
}
SurfaceOptions load_surface(const std::string& path) {
  return parse_surface(read_config_file(path), path);
}

}  // namespace canbridge::config
