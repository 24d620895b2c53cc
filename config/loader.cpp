#include "config/loader.hpp"

#include <yaml-cpp/yaml.h>

#include <charconv>
#include <optional>
#include <set>

#include "bridge/node_map.hpp"
#include "config/yaml_reader.hpp"

namespace canbridge::config {

namespace {

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

GatewayOptions load_gateway(const std::string& path) {
  return parse_gateway(read_config_file(path), path);
}
SurfaceOptions load_surface(const std::string& path) {
  return parse_surface(read_config_file(path), path);
}

}  // namespace canbridge::config
