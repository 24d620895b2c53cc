#include "config/backbone_auth_reader.hpp"

#include <arpa/inet.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "backbone/pre_shared_keys.hpp"
#include "routing/node_map.hpp"

namespace canbridge::config {

namespace {

constexpr const char* kModeChoices =
    "write 'mode: psk' (a pre-shared key file per gateway) or 'mode: certificates' (a private "
    "CA), or 'mode: plain' for a bench on loopback (nothing authenticated)";

// The key node of `key` in `map`, for the line an operator looks at when its value is empty or
// absent; an undefined node (false, line 0) if absent.
YAML::Node key_node(const YAML::Node& map, std::string_view key) {
  if (!map.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
  for (const auto& kv : map) {
    if (kv.first.Scalar() == key) return kv.first;
  }
  return YAML::Node(YAML::NodeType::Undefined);
}

int line_at(const YAML::Node& value, const YAML::Node& fallback) {
  const int line = value ? line_of(value) : 0;
  return line > 0 ? line : line_of(fallback);
}

std::optional<AuthMode> read_mode(YamlReader& in, const YAML::Node& auth,
                                  const YAML::Node& auth_key) {
  const YAML::Node mode = auth["mode"];
  if (!mode) {
    in.problem(line_of(auth_key), "backbone.auth.mode",
               std::string("missing (required): ") + kModeChoices);
    return std::nullopt;
  }
  const std::string text = mode.IsScalar() ? mode.Scalar() : std::string();
  if (text == "psk") return AuthMode::psk;
  if (text == "certificates") return AuthMode::certificates;
  if (text == "plain") return AuthMode::plain;
  in.problem(line_at(mode, auth_key), "backbone.auth.mode",
             "'" + text + "' is not one of psk, certificates, plain: " + kModeChoices);
  return std::nullopt;
}

// Loads a key file as the process will, so a key the process could not use (missing, readable
// by others, malformed) stops it now, at the line naming the file.
void check_key_file(YamlReader& in, const YAML::Node& value, const std::string& field,
                    const std::string& path) {
  const backbone::KeyFileResult keys = backbone::load_key_file(path);
  if (!keys.problem) return;
  std::string message = keys.problem->message;
  if (keys.problem->error == backbone::KeyFileError::cannot_open) {
    message +=
        " (make one: (umask 077; openssl rand -hex 32 > FILE), the same file at both ends; "
        "docs/security.md)";
  }
  in.problem(value, field, message);
}

// A certificate or CA file: there, readable, and a regular file of at most 1 MiB (TLS reads it
// whole at startup: /dev/zero would never end, a FIFO would wait for a writer). Its content is for
// TLS to judge.
void check_readable(YamlReader& in, const YAML::Node& value, const std::string& field,
                    const std::string& path) {
  struct stat status {};
  if (::access(path.c_str(), R_OK) != 0 || ::stat(path.c_str(), &status) != 0) {
    in.problem(value, field, path + ": cannot be read (" + std::strerror(errno) + ")");
  } else if (!S_ISREG(status.st_mode) ||
             static_cast<std::uint64_t>(status.st_size) > kMaxConfigFileBytes) {
    in.problem(value, field,
               path + ": must be a regular file of at most 1 MiB (" +
                   std::to_string(kMaxConfigFileBytes) + " bytes)");
  }
}

// A TLS private key: readable, and private like a key file (same owner and permission rule).
void check_private_key(YamlReader& in, const YAML::Node& value, const std::string& field,
                       const std::string& path) {
  struct stat status {};
  if (::stat(path.c_str(), &status) != 0) {
    in.problem(value, field, path + ": cannot be read (" + std::strerror(errno) + ")");
    return;
  }
  if (auto p = backbone::check_key_file_permissions(status, ::geteuid(), path)) {
    in.problem(value, field, p->message);
  }
}

// certificate, private_key and ca of `auth` (path `backbone.auth`): all three are needed on TCP.
void read_certificate_files(YamlReader& in, const YAML::Node& auth, const YAML::Node& auth_key,
                            bool required, AuthOptions& out) {
  struct File {
    const char* key;
    std::string AuthOptions::*field;
    bool private_key;
  };
  static const File kFiles[] = {
      {"certificate", &AuthOptions::certificate_file, false},
      {"private_key", &AuthOptions::private_key_file, true},
      {"ca", &AuthOptions::ca_file, false},
  };
  for (const File& f : kFiles) {
    const std::string field = std::string("backbone.auth.") + f.key;
    const YAML::Node value = auth[f.key];
    if (!value) {
      if (required) {
        in.problem(line_of(auth_key), field,
                   "missing (required) with mode certificates on TCP: a PEM file, e.g. "
                   "/etc/canbridge/keys/" +
                       std::string(f.key == std::string("ca") ? "ca.crt" : f.key));
      }
      continue;
    }
    auto path = in.file_path(auth, f.key, "backbone.auth", false);
    if (!path) continue;
    out.*f.field = *path;
    if (f.private_key) {
      check_private_key(in, value, field, *path);
    } else {
      check_readable(in, value, field, *path);
    }
  }
}

void read_mac_tag_bytes(YamlReader& in, const YAML::Node& auth, AuthOptions& out) {
  const YAML::Node value = auth["mac_tag_bytes"];
  if (!value) return;
  auto v = in.integer_text(value, "backbone.auth.mac_tag_bytes");
  if (!v) return;
  if (!v->negative && (v->magnitude == 16 || v->magnitude == 32)) {
    out.mac_tag_bytes = static_cast<std::size_t>(v->magnitude);
    return;
  }
  in.problem(
      value, "backbone.auth.mac_tag_bytes",
      value.Scalar() + " is not 16 or 32 (bytes of MAC per serial message; both ends agree)");
}

// The `auth` mapping under backbone, or nothing (reported) when it is absent or malformed.
std::optional<YAML::Node> auth_block(YamlReader& in, const YAML::Node& root) {
  const YAML::Node backbone = root["backbone"];
  if (!backbone || !backbone.IsMap()) return std::nullopt;  // reported by the transport reader
  const YAML::Node auth = backbone["auth"];
  if (!auth) {
    in.problem(key_node(root, "backbone"), "backbone.auth",
               std::string("missing (required): how this end proves who it is; ") + kModeChoices);
    return std::nullopt;
  }
  if (!auth.IsMap()) {
    in.problem(line_at(auth, key_node(backbone, "auth")), "backbone.auth",
               std::string("must be a mapping, e.g. {mode: psk, key_file: ...}; ") + kModeChoices);
    return std::nullopt;
  }
  return auth;
}

// Where plain operation would expose the bus to whoever reaches the address.
void check_plain_host(YamlReader& in, const YAML::Node& auth, const YAML::Node& auth_key,
                      const std::string& endpoint_field, const Endpoint& ep) {
  if (ep.host.empty() || is_loopback_host(ep.host)) return;
  in.problem(line_at(auth["mode"], auth_key), "backbone.auth.mode",
             "plain (nothing authenticated) is allowed only on a loopback address (127.0.0.0/8, "
             "::1, localhost) or a serial line, and " +
                 endpoint_field + " is " + ep.to_string() +
                 ": use mode psk or certificates (docs/security.md)");
}

bool valid_identity(const std::string& name) {
  if (name.empty() || name.size() > 64) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' ||
           c == '_' || c == '.';
  });
}

// A name that is an identity on the wire (PSK identity "<name>/<key id>", certificate name, hello
// name): refused (false) unless it is one every role can write.
bool check_identity(YamlReader& in, const YAML::Node& at, const std::string& field,
                    const std::string& name) {
  if (valid_identity(name)) return true;
  in.problem(at, field,
             "'" + name +
                 "' must be 1..64 letters, digits, '-', '_' or '.': it is an identity on the "
                 "backbone");
  return false;
}

// The role's own `name` (and a gateway's `auth.surface`), identities like the gateways' names.
void check_own_name(YamlReader& in, const YAML::Node& root, const std::string& name) {
  const YAML::Node node = root["name"];
  if (node && node.IsScalar() && !node.Scalar().empty()) check_identity(in, node, "name", name);
}

// "33-63, 65": node ids as ranges, for messages.
std::string ranges(const std::vector<std::uint8_t>& sorted) {
  std::string s;
  for (std::size_t i = 0; i < sorted.size();) {
    std::size_t j = i;
    while (j + 1 < sorted.size() && sorted[j + 1] == sorted[j] + 1) ++j;
    if (!s.empty()) s += ", ";
    s += std::to_string(sorted[i]);
    if (j > i) s += "-" + std::to_string(sorted[j]);
    i = j + 1;
  }
  return s;
}

// "node id 7" or "node ids 33-63, 65".
std::string node_ids(const std::vector<std::uint8_t>& sorted) {
  return (sorted.size() == 1 ? "node id " : "node ids ") + ranges(sorted);
}

// One `surface_nodes` item: a node id, or "a-b" (inclusive). Appends to `out`.
bool read_node_item(YamlReader& in, const YAML::Node& item, const std::string& field,
                    std::vector<std::uint8_t>& out) {
  const std::string text = item.IsScalar() ? item.Scalar() : std::string();
  const auto dash = text.find('-', 1);
  if (dash == std::string::npos) {
    auto v = in.integer(item, field, 1, 127);
    if (v) out.push_back(static_cast<std::uint8_t>(*v));
    return v.has_value();
  }
  const auto low = parse_integer(text.substr(0, dash));
  const auto high = parse_integer(text.substr(dash + 1));
  const bool numbers = low && high && low->fits(1, 127) && high->fits(1, 127);
  if (!numbers || low->magnitude > high->magnitude) {
    in.problem(
        item, field,
        "'" + text + "' is not a node id 1..127 or a range a-b of them (a <= b), e.g. 33-63");
    return false;
  }
  for (auto n = low->magnitude; n <= high->magnitude; ++n) {
    out.push_back(static_cast<std::uint8_t>(n));
  }
  return true;
}

struct GatewayClaims {
  std::vector<std::uint8_t> nodes;  // effective: given, or the default mapping of the modules
  bool nodes_known = false;
  YAML::Node at;  // where the nodes are written (or the item, for defaults)
};

// The surface nodes of gateways[i]: `surface_nodes`, or the default map of its modules.
GatewayClaims read_surface_nodes(YamlReader& in, const YAML::Node& item, const std::string& path,
                                 const AcceptedGatewayOptions& g, bool modules_ok) {
  GatewayClaims claims;
  const YAML::Node nodes = item["surface_nodes"];
  const std::string field = path + ".surface_nodes";
  if (!nodes) {
    claims.at = key_node(item, "modules") ? key_node(item, "modules") : item;
    if (!modules_ok) return claims;
    for (std::uint32_t module : g.modules) {
      if (module > bridge::kMaxDefaultModuleId) {
        in.problem(claims.at, field,
                   "missing: module " + std::to_string(module) +
                       " has no default surface node ids (32 x id + 1..31 would pass 127): give "
                       "surface_nodes, e.g. [1-31]");
        return claims;
      }
      for (const auto& [local, surface] : bridge::NodeMap::default_pairs(module)) {
        claims.nodes.push_back(surface);
      }
    }
    claims.nodes_known = true;
    return claims;
  }
  claims.at = nodes;
  if (!nodes.IsSequence() || nodes.size() == 0) {
    in.problem(line_at(nodes, key_node(item, "surface_nodes")), field,
               "must be a non-empty list of node ids and ranges, e.g. [33-63, 65]");
    return claims;
  }
  bool ok = true;
  for (std::size_t k = 0; k < nodes.size(); ++k) {
    ok = read_node_item(in, nodes[k], item_path(path, "surface_nodes", k), claims.nodes) && ok;
  }
  if (!ok) return claims;
  std::vector<std::uint8_t> sorted = claims.nodes;
  std::sort(sorted.begin(), sorted.end());
  std::vector<std::uint8_t> twice;
  for (std::size_t k = 1; k < sorted.size(); ++k) {
    if (sorted[k] == sorted[k - 1] && (twice.empty() || twice.back() != sorted[k])) {
      twice.push_back(sorted[k]);
    }
  }
  if (!twice.empty()) {
    in.problem(nodes, field,
               node_ids(twice) + (twice.size() == 1 ? " is" : " are") + " listed twice");
    return claims;
  }
  claims.nodes_known = true;
  return claims;
}

// One item of `gateways:`. Its modules and nodes are checked against the earlier items.
void read_accepted_gateway(YamlReader& in, const YAML::Node& item, std::size_t i,
                           std::map<std::string, std::size_t>& names,
                           std::map<std::uint32_t, std::size_t>& module_owner,
                           std::map<std::uint8_t, std::size_t>& node_owner, SurfaceOptions& out) {
  const std::string path = item_path("", "gateways", i);
  if (!item.IsMap()) {
    return in.problem(item, path, "must be a mapping with name, modules (and key_file for psk)");
  }
  in.only_keys(item, path, {"name", "modules", "surface_nodes", "key_file"});
  AcceptedGatewayOptions g;
  if (auto name = in.string(item, "name", path, true)) {
    g.name = *name;
    if (!check_identity(in, item["name"], path + ".name", *name)) {
    } else if (auto [it, fresh] = names.emplace(*name, i); !fresh) {
      in.problem(
          item["name"], path + ".name",
          "'" + *name + "' is also the name of gateways[" + std::to_string(it->second) + "]");
    }
  }
  bool modules_ok = false;
  const YAML::Node modules = item["modules"];
  if (!modules) {
    in.problem(item, path + ".modules",
               "missing (required): the module ids it serves, e.g. [1, 2]");
  } else if (!modules.IsSequence() || modules.size() == 0) {
    in.problem(line_at(modules, key_node(item, "modules")), path + ".modules",
               "must be a non-empty list of module ids, e.g. [1, 2]");
  } else {
    modules_ok = true;
    for (std::size_t k = 0; k < modules.size(); ++k) {
      const std::string field = item_path(path, "modules", k);
      auto id = in.integer(modules[k], field, 0, 0xFFFFFFFELL);
      if (!id) {
        modules_ok = false;
        continue;
      }
      const auto module = static_cast<std::uint32_t>(*id);
      if (auto [it, fresh] = module_owner.emplace(module, i); !fresh) {
        in.problem(
            modules[k], field,
            "module " + std::to_string(module) +
                (it->second == i ? " is listed twice"
                                 : " is also claimed by gateways[" + std::to_string(it->second) +
                                       "]: a module has one gateway"));
        modules_ok = false;
        continue;
      }
      g.modules.push_back(module);
    }
  }
  GatewayClaims claims = read_surface_nodes(in, item, path, g, modules_ok);
  if (item["surface_nodes"] && claims.nodes_known) g.surface_nodes = claims.nodes;
  if (claims.nodes_known) {
    std::map<std::size_t, std::vector<std::uint8_t>> clashes;  // earlier gateway -> its nodes here
    for (std::uint8_t n : claims.nodes) {
      if (auto [it, fresh] = node_owner.emplace(n, i); !fresh && it->second != i) {
        clashes[it->second].push_back(n);
      }
    }
    for (auto& [other, nodes] : clashes) {
      std::sort(nodes.begin(), nodes.end());
      in.problem(claims.at, path + ".surface_nodes",
                 "surface " + node_ids(nodes) + (nodes.size() == 1 ? " is" : " are") +
                     " also claimed by gateways[" + std::to_string(other) + "]" +
                     (item["surface_nodes"] ? "" : " (here: the default ids of its modules)"));
    }
  }
  if (auto key_file = in.file_path(item, "key_file", path, false)) {
    g.key_file = *key_file;
    check_key_file(in, item["key_file"], path + ".key_file", *key_file);
  }
  out.gateways.push_back(std::move(g));
}

void read_accepted_gateways(YamlReader& in, const YAML::Node& root, SurfaceOptions& out) {
  const YAML::Node list = root["gateways"];
  if (!list) {
    return in.problem(root, "gateways",
                      "missing (required): the gateways this surface accepts, each with name and "
                      "modules (and key_file for psk): no other peer is ever bound");
  }
  if (!list.IsSequence() || list.size() == 0) {
    return in.problem(line_at(list, key_node(root, "gateways")), "gateways",
                      "must be a non-empty list of the gateways this surface accepts");
  }
  std::map<std::string, std::size_t> names;
  std::map<std::uint32_t, std::size_t> module_owner;
  std::map<std::uint8_t, std::size_t> node_owner;
  for (std::size_t i = 0; i < list.size(); ++i) {
    read_accepted_gateway(in, list[i], i, names, module_owner, node_owner, out);
  }
}

// psk: every configured gateway has a key; certificates with serial lines: the lines' gateways.
void check_gateway_keys(YamlReader& in, const YAML::Node& root, const SurfaceOptions& out) {
  if (out.auth.mode != AuthMode::psk) return;
  const YAML::Node list = root["gateways"];
  for (std::size_t i = 0; i < out.gateways.size() && i < list.size(); ++i) {
    if (out.gateways[i].key_file.empty() && !list[i]["key_file"]) {
      in.problem(
          list[i], item_path("", "gateways", i) + ".key_file",
          "missing (required) with mode psk: the file of the key this gateway shares "
          "with the surface, e.g. /etc/canbridge/keys/" +
              (out.gateways[i].name.empty() ? std::string("gateway") : out.gateways[i].name) +
              ".key");
    }
  }
}

// Each serial line of a surface names the gateway it serves; the line is authenticated with
// that gateway's key unless the surface is plain.
void read_line_gateways(YamlReader& in, const YAML::Node& root, SurfaceOptions& out) {
  const YAML::Node backbone = root["backbone"];
  const YAML::Node lines = backbone["serial"];
  if (!lines || !lines.IsSequence()) return;
  const bool plain = out.auth.mode == AuthMode::plain;
  std::map<std::string, std::size_t> served;  // gateway name -> its line
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const YAML::Node line = lines[i];
    if (!line.IsMap()) continue;  // reported by the line reader
    const std::string path = item_path("backbone", "serial", i);
    const YAML::Node gateway = line["gateway"];
    if (!gateway) {
      if (!plain) {
        in.problem(line, path + ".gateway",
                   "missing (required) unless mode is plain: the name of the configured gateway "
                   "this line serves (its key authenticates the line)");
      }
      continue;
    }
    auto name = in.string(line, "gateway", path, false);
    if (!name) continue;
    const auto g = std::find_if(out.gateways.begin(), out.gateways.end(),
                                [&](const AcceptedGatewayOptions& a) { return a.name == *name; });
    if (g == out.gateways.end()) {
      in.problem(gateway, path + ".gateway",
                 "'" + *name + "' is not the name of a gateway in 'gateways'");
    } else if (auto [it, fresh] = served.emplace(*name, i); !fresh) {
      in.problem(gateway, path + ".gateway",
                 "gateway '" + *name + "' is also served by backbone.serial[" +
                     std::to_string(it->second) + "]: a gateway has one line");
    } else if (!plain && g->key_file.empty()) {
      in.problem(gateway, path + ".gateway",
                 "gateway '" + *name +
                     "' has no key_file: a serial line is authenticated with the gateway's "
                     "pre-shared key, give gateways[" +
                     std::to_string(g - out.gateways.begin()) + "].key_file");
    }
    // The surface's line list skips refused lines: match by device.
    const YAML::Node device = line["device"];
    for (SerialLineOptions& l : out.serial) {
      if (device && device.IsScalar() && l.device == device.Scalar()) l.gateway = *name;
    }
  }
}

void read_admission(YamlReader& in, const YAML::Node& backbone, AdmissionOptions& out) {
  const YAML::Node block = backbone["admission"];
  if (!block) return;
  if (!block.IsMap()) {
    return in.problem(line_at(block, key_node(backbone, "admission")), "backbone.admission",
                      "must be a mapping, e.g. {max_pending_handshakes: 32, "
                      "handshake_timeout_ms: 2000, max_links: 0}");
  }
  const std::string path = "backbone.admission";
  in.only_keys(block, path, {"max_pending_handshakes", "handshake_timeout_ms", "max_links"});
  if (auto v = in.integer(block, "max_pending_handshakes", path, 1, 65536)) {
    out.max_pending_handshakes = static_cast<std::size_t>(*v);
  }
  if (auto v = in.integer(block, "handshake_timeout_ms", path, 1, 600000)) {
    out.handshake_timeout = std::chrono::milliseconds(*v);
  }
  // 0 is "four per configured gateway plus eight", not "none".
  if (auto v = in.integer(block, "max_links", path, 0, 65536)) {
    out.max_links = static_cast<std::size_t>(*v);
  }
}

}  // namespace

bool is_loopback_host(const std::string& host) {
  if (host == "localhost") return true;
  std::string h = host;
  if (h.size() >= 2 && h.front() == '[' && h.back() == ']') h = h.substr(1, h.size() - 2);
  in_addr v4{};
  if (::inet_pton(AF_INET, h.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (::inet_pton(AF_INET6, h.c_str(), &v6) == 1) {
    return std::memcmp(&v6, &in6addr_loopback, sizeof v6) == 0;
  }
  return false;
}

void read_gateway_auth(YamlReader& in, const YAML::Node& root, GatewayOptions& out) {
  const auto auth = auth_block(in, root);
  if (!auth) return;
  const YAML::Node auth_key = key_node(root["backbone"], "auth");
  in.only_keys(
      *auth, "backbone.auth",
      {"mode", "key_file", "surface", "certificate", "private_key", "ca", "mac_tag_bytes"});
  const auto mode = read_mode(in, *auth, auth_key);
  if (mode) out.auth.mode = *mode;
  check_own_name(in, root, out.name);
  if (auto surface = in.string(*auth, "surface", "backbone.auth", false)) {
    out.auth.surface = *surface;
    check_identity(in, (*auth)["surface"], "backbone.auth.surface", *surface);
  }
  read_mac_tag_bytes(in, *auth, out.auth);
  const bool tcp = !out.connect.host.empty();
  read_certificate_files(in, *auth, auth_key, mode == AuthMode::certificates && tcp, out.auth);
  if (auto key_file = in.file_path(*auth, "key_file", "backbone.auth", false)) {
    out.auth.key_file = *key_file;
    check_key_file(in, (*auth)["key_file"], "backbone.auth.key_file", *key_file);
  } else if (!(*auth)["key_file"] &&
             (mode == AuthMode::psk || (mode == AuthMode::certificates && out.serial))) {
    in.problem(line_of(auth_key), "backbone.auth.key_file",
               std::string("missing (required) with mode ") +
                   (mode == AuthMode::psk ? "psk" : "certificates on a serial line") +
                   ": the file of the key this gateway shares with the surface, e.g. "
                   "/etc/canbridge/keys/" +
                   out.name + ".key (docs/security.md)");
  }
  if (mode == AuthMode::plain)
    check_plain_host(in, *auth, auth_key, "backbone.connect", out.connect);
}

void read_surface_auth(YamlReader& in, const YAML::Node& root, SurfaceOptions& out) {
  read_accepted_gateways(in, root, out);
  const YAML::Node backbone = root["backbone"];
  if (backbone && backbone.IsMap()) read_admission(in, backbone, out.admission);
  const auto auth = auth_block(in, root);
  if (!auth) return;
  const YAML::Node auth_key = key_node(backbone, "auth");
  check_own_name(in, root, out.name);
  in.only_keys(*auth, "backbone.auth",
               {"mode", "key_file", "certificate", "private_key", "ca", "mac_tag_bytes"});
  if ((*auth)["key_file"]) {
    in.problem(key_node(*auth, "key_file"), "backbone.auth.key_file",
               "a surface has one key per gateway: give it as gateways[].key_file");
  }
  const auto mode = read_mode(in, *auth, auth_key);
  if (mode) out.auth.mode = *mode;
  read_mac_tag_bytes(in, *auth, out.auth);
  const bool tcp = !out.listen.host.empty();
  read_certificate_files(in, *auth, auth_key, mode == AuthMode::certificates && tcp, out.auth);
  if (mode == AuthMode::plain) check_plain_host(in, *auth, auth_key, "backbone.listen", out.listen);
  if (!mode) return;  // which lines need keys depends on the mode
  check_gateway_keys(in, root, out);
  read_line_gateways(in, root, out);
}

}  // namespace canbridge::config
