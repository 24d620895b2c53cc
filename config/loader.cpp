#include "config/loader.hpp"

#include <yaml-cpp/yaml.h>

#include <charconv>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>

#include "bridge/node_map.hpp"

namespace canbridge::config {

std::string ConfigProblem::to_string() const {
  std::string s = file;
  if (line > 0) s.append(":").append(std::to_string(line));
  s += ": ";
  if (!field.empty()) s += field + ": ";
  return s + message;
}

namespace {

std::string join(const std::vector<ConfigProblem>& problems) {
  std::string s = "invalid configuration (" + std::to_string(problems.size()) + " problem" +
                  (problems.size() == 1 ? "" : "s") + ")";
  for (const auto& p : problems) s += "\n  " + p.to_string();
  return s;
}

// Walks a YAML document collecting problems instead of stopping at the first one.
class Reader {
 public:
  explicit Reader(std::string file) : file_(std::move(file)) {}

  void problem(const YAML::Node& at, const std::string& field, const std::string& message) {
    int line = 0;
    if (at.IsDefined() && at.Mark().line >= 0) line = at.Mark().line + 1;
    problems_.push_back({file_, line, field, message});
  }

  // Every key of `map` must be one of `known`: a typo must not silently become a default.
  void only_keys(const YAML::Node& map, const std::string& path,
                 std::initializer_list<const char*> known) {
    if (!map.IsMap()) return;
    for (const auto& kv : map) {
      const std::string key = kv.first.Scalar();
      bool ok = false;
      for (const char* k : known) ok = ok || key == k;
      if (!ok) problem(kv.first, join_path(path, key), "unknown key");
    }
  }

  std::optional<std::string> string(const YAML::Node& map, const char* key, const std::string& path,
                                    bool required) {
    const YAML::Node node = map[key];
    const std::string field = join_path(path, key);
    if (!node) {
      if (required) problem(map, field, "missing (required)");
      return std::nullopt;
    }
    if (!node.IsScalar() || node.Scalar().empty()) {
      problem(node, field, "must be a non-empty string");
      return std::nullopt;
    }
    return node.Scalar();
  }

  std::optional<long long> integer(const YAML::Node& node, const std::string& field, long long min,
                                   long long max) {
    if (!node.IsScalar()) {
      problem(node, field, "must be an integer");
      return std::nullopt;
    }
    const std::string& s = node.Scalar();
    long long v = 0;
    int base = 10;
    const char* begin = s.data();
    if (s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
      base = 16;
      begin += 2;
    }
    auto [ptr, ec] = std::from_chars(begin, s.data() + s.size(), v, base);
    if (ec != std::errc{} || ptr != s.data() + s.size()) {
      problem(node, field, "'" + s + "' is not an integer");
      return std::nullopt;
    }
    if (v < min || v > max) {
      problem(node, field,
              std::to_string(v) + " is out of range " + std::to_string(min) + ".." +
                  std::to_string(max));
      return std::nullopt;
    }
    return v;
  }

  std::optional<long long> integer(const YAML::Node& map, const char* key, const std::string& path,
                                   long long min, long long max, bool required) {
    const YAML::Node node = map[key];
    if (!node) {
      if (required) problem(map, join_path(path, key), "missing (required)");
      return std::nullopt;
    }
    return integer(node, join_path(path, key), min, max);
  }

  std::optional<bool> boolean(const YAML::Node& map, const char* key, const std::string& path) {
    const YAML::Node node = map[key];
    if (!node) return std::nullopt;
    bool v = false;
    if (!node.IsScalar() || !YAML::convert<bool>::decode(node, v)) {
      problem(node, join_path(path, key), "must be true or false");
      return std::nullopt;
    }
    return v;
  }

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

  [[noreturn]] void fail() { throw ConfigError(problems_); }
  void finish() {
    if (!problems_.empty()) fail();
  }

  static std::string join_path(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }

 private:
  std::string file_;
  std::vector<ConfigProblem> problems_;
};

YAML::Node parse_root(std::string_view yaml, const std::string& file, const char* role) {
  YAML::Node root;
  try {
    root = YAML::Load(std::string(yaml));
  } catch (const YAML::ParserException& e) {
    throw ConfigError({{file, e.mark.line + 1, "", "YAML syntax error: " + e.msg}});
  }
  if (!root.IsMap()) throw ConfigError({{file, 0, "", "the file must be a YAML mapping"}});
  const YAML::Node r = root["role"];
  if (!r || !r.IsScalar() || r.Scalar() != role) {
    const int line = r && r.Mark().line >= 0 ? r.Mark().line + 1 : 0;
    throw ConfigError(
        {{file, line, "role", std::string("must be '") + role + "' for this command"}});
  }
  return root;
}

void read_modules(Reader& in, const YAML::Node& root, GatewayOptions& out) {
  const YAML::Node modules = root["modules"];
  if (!modules) return in.problem(root, "modules", "missing (required): at least one module");
  if (!modules.IsSequence() || modules.size() == 0) {
    return in.problem(modules, "modules", "must be a non-empty list");
  }
  bridge::NodeMap map;
  std::set<std::string> buses;
  for (std::size_t i = 0; i < modules.size(); ++i) {
    const YAML::Node m = modules[i];
    const std::string path = "modules[" + std::to_string(i) + "]";
    if (!m.IsMap()) {
      in.problem(m, path, "must be a mapping with id and bus");
      continue;
    }
    in.only_keys(m, path, {"id", "bus", "nodes"});
    ModuleOptions module;
    auto id = in.integer(m, "id", path, 0, 0xFFFFFFFELL, true);
    auto bus = in.string(m, "bus", path, true);
    if (bus && !buses.insert(*bus).second) {
      in.problem(m["bus"], path + ".bus", "bus '" + *bus + "' is used by two modules");
    }
    if (bus && bus->size() >= 16) {
      in.problem(m["bus"], path + ".bus", "interface names are at most 15 characters");
    }
    const YAML::Node nodes = m["nodes"];
    bool nodes_ok = true;
    if (nodes) {
      module.default_nodes = false;
      if (!nodes.IsMap() || nodes.size() == 0) {
        in.problem(nodes, path + ".nodes",
                   "must map local node ids to surface node ids, e.g. {1: 33}");
        nodes_ok = false;
      } else {
        for (const auto& kv : nodes) {
          const std::string field = path + ".nodes." + kv.first.Scalar();
          auto local = in.integer(kv.first, field, 1, 127);
          auto surface = in.integer(kv.second, field, 1, 127);
          if (local && surface) {
            module.nodes.emplace_back(static_cast<std::uint8_t>(*local),
                                      static_cast<std::uint8_t>(*surface));
          } else {
            nodes_ok = false;
          }
        }
      }
    } else if (id && *id > bridge::kMaxDefaultModuleId) {
      in.problem(m["id"], path + ".id",
                 "modules above " + std::to_string(bridge::kMaxDefaultModuleId) +
                     " have no default node map (local + 32 x id would pass 127): give 'nodes'");
      nodes_ok = false;
    }
    if (!id || !bus) continue;
    module.id = static_cast<std::uint32_t>(*id);
    module.bus = *bus;
    if (module.default_nodes) module.nodes = bridge::NodeMap::default_pairs(module.id);
    if (nodes_ok) {
      for (const std::string& p : map.add_module(module.id, module.nodes)) {
        in.problem(nodes ? nodes : m, path, p);
      }
    }
    out.modules.push_back(std::move(module));
  }
}

}  // namespace

ConfigError::ConfigError(std::vector<ConfigProblem> problems)
    : std::runtime_error(join(problems)), problems_(std::move(problems)) {}

GatewayOptions parse_gateway(std::string_view yaml, const std::string& file) {
  const YAML::Node root = parse_root(yaml, file, "gateway");
  Reader in(file);
  in.only_keys(root, "", {"role", "name", "backbone", "modules", "can", "log"});
  GatewayOptions out;
  if (auto name = in.string(root, "name", "", false)) out.name = *name;
  const YAML::Node backbone = root["backbone"];
  if (!backbone || !backbone.IsMap()) {
    in.problem(backbone ? backbone : root, "backbone",
               "missing (required): needs 'connect: host:port'");
  } else {
    in.only_keys(backbone, "backbone", {"connect", "reconnect_min_ms", "reconnect_max_ms"});
    if (auto ep = in.endpoint(backbone, "connect", "backbone", true)) {
      if (ep->port == 0) {
        in.problem(backbone["connect"], "backbone.connect", "port 0 cannot be connected to");
      }
      out.connect = *ep;
    }
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
  read_modules(in, root, out);
  in.can_options(root, out.can);
  in.log_options(root, out.log);
  in.finish();
  return out;
}

SurfaceOptions parse_surface(std::string_view yaml, const std::string& file) {
  const YAML::Node root = parse_root(yaml, file, "surface");
  Reader in(file);
  in.only_keys(root, "", {"role", "name", "backbone", "bus", "can", "log"});
  SurfaceOptions out;
  if (auto name = in.string(root, "name", "", false)) out.name = *name;
  if (auto bus = in.string(root, "bus", "", true)) out.bus = *bus;
  const YAML::Node backbone = root["backbone"];
  if (!backbone || !backbone.IsMap()) {
    in.problem(backbone ? backbone : root, "backbone",
               "missing (required): needs 'listen: host:port'");
  } else {
    in.only_keys(backbone, "backbone", {"listen"});
    if (auto ep = in.endpoint(backbone, "listen", "backbone", true)) out.listen = *ep;
  }
  in.can_options(root, out.can);
  in.log_options(root, out.log);
  in.finish();
  return out;
}

namespace {
std::string read_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError({{path, 0, "", "cannot open the file"}});
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}
}  // namespace

GatewayOptions load_gateway(const std::string& path) {
  return parse_gateway(read_file(path), path);
}
SurfaceOptions load_surface(const std::string& path) {
  return parse_surface(read_file(path), path);
}

}  // namespace canbridge::config
