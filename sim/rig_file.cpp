#include "sim/rig_file.hpp"

#include <yaml-cpp/yaml.h>

#include <bit>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <optional>
#include <set>

#include "canopen/little_endian.hpp"
#include "yaml/yaml_reader.hpp"

namespace canbridge::sim {

namespace {

struct KindName {
  NodeKind kind;
  const char* name;
};

constexpr KindName kKinds[] = {
    {NodeKind::microcanopen, "microcanopen"},
    {NodeKind::qd, "qd"},
    {NodeKind::fpga, "fpga"},
    {NodeKind::cia301, "cia301"},
};

}  // namespace

std::optional<NodeKind> parse_node_kind(std::string_view name) {
  for (const auto& k : kKinds) {
    if (name == k.name) return k.kind;
  }
  return std::nullopt;
}

const char* to_string(NodeKind kind) {
  for (const auto& k : kKinds) {
    if (k.kind == kind) return k.name;
  }
  return "?";
}

namespace {

using config::ConfigError;
using config::ConfigProblem;
using config::hex;
using config::Integer;
using config::item_path;
using config::join_path;
using config::line_of;
using config::parse_integer;

// Highest node id of the kinds that take the identifiers of nodes N+32, N+64 and N+96 (qd: the
// extended connection set of seeds/003; fpga: the t and c bits of PDO Packets, seeds/000).
constexpr int kMaxShortNodeId = 31;
constexpr int kMaxQdTpdos = 34;
constexpr int kMaxStandardPdos = 4;
constexpr int kMaxPdoBits = 64;
constexpr std::size_t kMaxPdopPacketBytes = 524280;  // docs/pdop.md section 5

// "6000:01", as objects are written in PDO maps and counters.
std::string object_name(std::uint16_t index, std::uint8_t sub) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%04X:%02X", index, sub);
  return buf;
}

// A floating-point number: decimal, integer (also hex) or YAML's .inf / -.inf / .nan.
std::optional<double> parse_real(std::string_view s) {
  if (auto i = parse_integer(s); i && !i->overflow) {
    const double m = static_cast<double>(i->magnitude);
    return i->negative ? -m : m;
  }
  static const std::map<std::string_view, double> kSpecial = {
      {".inf", HUGE_VAL},   {".Inf", HUGE_VAL},     {".INF", HUGE_VAL},     {"+.inf", HUGE_VAL},
      {"+.Inf", HUGE_VAL},  {"+.INF", HUGE_VAL},    {"-.inf", -HUGE_VAL},   {"-.Inf", -HUGE_VAL},
      {"-.INF", -HUGE_VAL}, {".nan", std::nan("")}, {".NaN", std::nan("")}, {".NAN", std::nan("")},
  };
  if (auto it = kSpecial.find(s); it != kSpecial.end()) return it->second;
  if (!s.empty() && s[0] == '+') s.remove_prefix(1);
  double v = 0;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (s.empty() || ec != std::errc{} || ptr != s.data() + s.size()) return std::nullopt;
  return v;
}

std::vector<std::uint8_t> le(std::uint64_t value, std::size_t size) {
  std::vector<std::uint8_t> out(size);
  canopen::store_le(value, out);
  return out;
}

bool is_signed_integer(DataType t) {
  return t == DataType::integer8 || t == DataType::integer16 || t == DataType::integer32 ||
         t == DataType::integer64;
}
bool is_unsigned_integer(DataType t) {
  return t == DataType::unsigned8 || t == DataType::unsigned16 || t == DataType::unsigned32 ||
         t == DataType::unsigned64;
}

using ObjectRef = std::pair<std::uint16_t, std::uint8_t>;

// "6000:01": hex index of 1..4 digits, hex sub-index of 1..2 digits.
std::optional<ObjectRef> parse_object_ref(std::string_view s) {
  const auto colon = s.find(':');
  if (colon == std::string_view::npos || colon == 0 || colon > 4) return std::nullopt;
  const std::size_t sub_len = s.size() - colon - 1;
  if (sub_len == 0 || sub_len > 2) return std::nullopt;
  unsigned index = 0;
  unsigned sub = 0;
  auto [p1, e1] = std::from_chars(s.data(), s.data() + colon, index, 16);
  auto [p2, e2] = std::from_chars(s.data() + colon + 1, s.data() + s.size(), sub, 16);
  if (e1 != std::errc{} || p1 != s.data() + colon || e2 != std::errc{} ||
      p2 != s.data() + s.size()) {
    return std::nullopt;
  }
  return ObjectRef{static_cast<std::uint16_t>(index), static_cast<std::uint8_t>(sub)};
}

// The shared YAML reader plus what only rig files name: objects as index:sub.
class Reader : public config::YamlReader {
 public:
  using YamlReader::YamlReader;

  // "6000:01" (hex index, hex sub-index), as in EDS files and CANopen tools.
  std::optional<ObjectRef> object_ref(const YAML::Node& node, const std::string& field) {
    std::optional<ObjectRef> ref;
    if (node.IsScalar()) ref = parse_object_ref(node.Scalar());
    if (!ref) problem(node, field, "must name an object as index:sub in hex, e.g. \"6000:01\"");
    return ref;
  }
};

// What later rules need to know about an object the node declares, including one whose value
// was refused: a PDO mapping it must not also be reported as naming a missing object.
struct DeclaredObject {
  std::optional<DataType> type;
  Access access = Access::rw;
  std::size_t bytes = 0;  // the value's size (0: unknown)
  int line = 0;
};
using ObjectTable = std::map<std::uint32_t, DeclaredObject>;

struct DeclaredPdo {
  bool enabled = true;
  int line = 0;
};

// One node as read, with what the bus-wide rules need.
struct NodeRead {
  std::optional<NodeKind> kind;
  std::optional<int> node_id;
  int node_id_line = 0;
  std::string path;
  NodeSpec spec;
  struct ExplicitTpdo {
    std::uint32_t cob_id;
    unsigned number;
    YAML::Node at;
    std::string field;
  };
  std::vector<ExplicitTpdo> explicit_tpdos;
};

// Objects the node builds itself, from its dedicated keys or its kind (docs/sim-nodes.md): a rig
// object of the same index would fight them.
std::optional<std::string> owner_of(std::uint16_t index, std::optional<NodeKind> kind) {
  switch (index) {
    case 0x1000:
      return "1000h comes from device_type";
    case 0x1001:
      return "1001h (error register) belongs to the node's EMCY logic";
    case 0x1003:
      return "1003h (error history) belongs to the node's EMCY logic";
    case 0x1014:
      return "1014h (COB-ID EMCY) is 0x80 + node id";
    case 0x1015:
      return "1015h comes from emcy.inhibit_100us";
    case 0x1017:
      return "1017h comes from heartbeat_ms";
    case 0x1018:
      return "1018h comes from identity";
    default:
      break;
  }
  if (index >= 0x1400 && index <= 0x1BFF) {
    return hex(index, 4) + " is a PDO communication or mapping object: use tpdos/rpdos";
  }
  if (index < 0x1000) return "0000h-0FFFh hold data type definitions, not values";
  if (kind == NodeKind::qd && index >= 0x1F50 && index <= 0x1F57) {
    return hex(index, 4) + " is a qd loader download object (1F50h-1F57h), built by the node";
  }
  if (kind == NodeKind::qd && (index == 0x2F00 || index == 0x2F01)) {
    return hex(index, 4) +
           " is the qd event reset register (2F00h) or EMCY hold-off (2F01h): use "
           "emcy.holdoff_ms";
  }
  if (kind == NodeKind::fpga && index == 0x5F00) {
    return "5F00h counts the fpga node's received PDO Packets, built by the node";
  }
  return std::nullopt;
}

// CiA 301 7.3.5: identifiers no PDO may use (NMT, SYNC/EMCY-less low range, TIME, SDO,
// NMT error control, LSS and the reserved tail).
bool restricted_cob_id(std::uint32_t id) {
  return id <= 0x07F || (id >= 0x101 && id <= 0x180) || (id >= 0x581 && id <= 0x5FF) ||
         (id >= 0x601 && id <= 0x67F) || (id >= 0x6E0 && id <= 0x6FF) || id >= 0x701;
}

std::uint16_t predefined_pdo_base(bool transmit, unsigned number) {
  const auto step = static_cast<std::uint16_t>(0x100 * (number - 1));
  return static_cast<std::uint16_t>((transmit ? 0x180 : 0x200) + step);
}

class RigReader {
 public:
  explicit RigReader(Reader& in) : in_(in) {}

  RigSpec read(const YAML::Node& root) {
    RigSpec rig;
    in_.only_keys(root, "", {"rig", "description", "buses"});
    if (auto name = in_.string(root, "rig", "", false)) rig.name = *name;
    if (const YAML::Node d = root["description"]) {
      if (d.IsScalar()) {
        rig.description = d.Scalar();
      } else {
        in_.problem(d, "description", "must be a string");
      }
    }
    const YAML::Node buses = root["buses"];
    if (!buses) {
      in_.problem(root, "buses", "missing (required): at least one bus");
      return rig;
    }
    if (!buses.IsSequence() || buses.size() == 0) {
      in_.problem(buses, "buses", "must be a non-empty list of buses");
      return rig;
    }
    std::map<std::string, int> names;
    std::map<std::string, int> interfaces;
    for (std::size_t i = 0; i < buses.size(); ++i) {
      const YAML::Node b = buses[i];
      const std::string path = item_path("", "buses", i);
      if (!b.IsMap()) {
        in_.problem(b, path, "must be a mapping with name and nodes");
        continue;
      }
      BusSpec bus = read_bus(b, path);
      if (!bus.name.empty()) {
        if (auto [it, fresh] = names.emplace(bus.name, line_of(b["name"])); !fresh) {
          in_.problem(
              b["name"], path + ".name",
              "bus '" + bus.name + "' is already defined at line " + std::to_string(it->second));
        }
      }
      if (!bus.interface.empty()) {
        if (auto [it, fresh] = interfaces.emplace(bus.interface, line_of(b["interface"])); !fresh) {
          in_.problem(b["interface"], path + ".interface",
                      "interface '" + bus.interface + "' is already used by the bus at line " +
                          std::to_string(it->second) + ": two buses cannot share one CAN network");
        }
      }
      rig.buses.push_back(std::move(bus));
    }
    return rig;
  }

 private:
  BusSpec read_bus(const YAML::Node& b, const std::string& path) {
    BusSpec bus;
    in_.only_keys(b, path, {"name", "interface", "nodes"});
    if (auto name = in_.string(b, "name", path, true)) bus.name = *name;
    if (auto itf = in_.interface_name(b, "interface", path, false)) bus.interface = *itf;
    auto nodes = in_.list(b, "nodes", path);
    if (!nodes) return bus;
    std::vector<NodeRead> read;
    for (std::size_t i = 0; i < nodes->size(); ++i) {
      const YAML::Node n = (*nodes)[i];
      const std::string node_path = item_path(path, "nodes", i);
      if (!n.IsMap()) {
        in_.problem(n, node_path, "must be a mapping with name, kind and node_id");
        continue;
      }
      read.push_back(read_node(n, node_path));
    }
    check_bus(read);
    for (auto& r : read) bus.nodes.push_back(std::move(r.spec));
    return bus;
  }

  // Rules between the nodes of one bus.
  void check_bus(const std::vector<NodeRead>& nodes) {
    const auto by_id = check_unique_ids(nodes);
    check_borrowed_ids(nodes, by_id);
    check_tpdo_transmitters(nodes);
  }

  std::map<int, const NodeRead*> check_unique_ids(const std::vector<NodeRead>& nodes) {
    std::map<int, const NodeRead*> by_id;
    for (const auto& n : nodes) {
      if (!n.node_id) continue;
      if (auto [it, fresh] = by_id.emplace(*n.node_id, &n); !fresh) {
        in_.problem(n.node_id_line, n.path + ".node_id",
                    "node id " + std::to_string(*n.node_id) + " is already used on this bus by " +
                        describe(*it->second) + " (line " +
                        std::to_string(it->second->node_id_line) + ")");
      }
    }
    return by_id;
  }

  // qd (extended connection set) and fpga (PDO Packet t/c bits) nodes transmit on the
  // identifiers of nodes N+32, N+64 and N+96 as well as their own.
  void check_borrowed_ids(const std::vector<NodeRead>& nodes,
                          const std::map<int, const NodeRead*>& by_id) {
    for (const auto& n : nodes) {
      if (!n.node_id || *n.node_id <= kMaxShortNodeId) continue;
      auto it = by_id.find(*n.node_id & kMaxShortNodeId);
      if (it == by_id.end() || !it->second->kind) continue;
      const NodeKind k = *it->second->kind;
      if (k != NodeKind::qd && k != NodeKind::fpga) continue;
      in_.problem(n.node_id_line, n.path + ".node_id",
                  "node id " + std::to_string(*n.node_id) + " collides with " +
                      describe(*it->second) + ": " +
                      (k == NodeKind::qd ? "a qd node takes the PDO and SDO identifiers of "
                                           "nodes N+32, N+64 and N+96 (seeds/003)"
                                         : "an fpga node's PDO Packets use the identifiers of "
                                           "nodes N+32, N+64 and N+96 (t and c bits, seeds/000)"));
    }
  }

  // An explicit TPDO COB-ID must have one transmitter: CAN arbitration cannot resolve two
  // stations sending the same identifier.
  void check_tpdo_transmitters(const std::vector<NodeRead>& nodes) {
    std::map<std::uint32_t, std::string> users;
    for (const auto& n : nodes) add_predefined_transmitters(n, users);
    for (const auto& n : nodes) {
      for (const auto& t : n.explicit_tpdos) {
        auto [it, fresh] =
            users.emplace(t.cob_id, describe(n) + " TPDO " + std::to_string(t.number));
        if (!fresh) {
          in_.problem(t.at, t.field,
                      hex(t.cob_id, 3) + " is already transmitted by " + it->second +
                          ": one identifier, one transmitter");
        }
      }
    }
  }

  // The identifiers a node transmits on without an explicit cob_id, by who sends them.
  static void add_predefined_transmitters(const NodeRead& n,
                                          std::map<std::uint32_t, std::string>& users) {
    if (!n.node_id || !n.kind) return;
    const auto id = static_cast<std::uint32_t>(*n.node_id);
    for (const auto& t : n.spec.tpdos) {
      if (t.cob_id || t.number > kMaxStandardPdos) continue;
      const std::uint32_t base = predefined_pdo_base(true, t.number);
      const std::string who = describe(n) + " TPDO " + std::to_string(t.number);
      users.emplace(base + id, who);
      if (*n.kind == NodeKind::fpga) {
        for (std::uint32_t tc = 0x20; tc <= 0x60; tc += 0x20) {
          users.emplace(base | tc | id, who + " (PDO Packet fragments)");
        }
      }
    }
    if (*n.kind == NodeKind::qd) {
      // Every PDO-range identifier ending in the qd node's id may be one of its 34 TPDOs.
      // Its own four RPDOs (0x200 + N, ...) are receive identifiers others may send to.
      for (std::uint32_t cob = 0x180; cob < 0x580; cob += 0x20) {
        if ((cob & 0x7F) == 0 && (cob & 0x80) == 0) continue;
        users.emplace(cob | id, describe(n) + " (extended connection set)");
      }
    }
  }

  static std::string describe(const NodeRead& n) {
    std::string s = n.kind ? std::string(to_string(*n.kind)) + " node " : "node ";
    s += n.node_id ? std::to_string(*n.node_id) : "?";
    if (!n.spec.name.empty()) s += " '" + n.spec.name + "'";
    return s;
  }

  NodeRead read_node(const YAML::Node& n, const std::string& path) {
    NodeRead r;
    r.path = path;
    NodeSpec& spec = r.spec;
    in_.only_keys(
        n, path,
        {"name", "kind", "node_id", "device_type", "identity", "heartbeat_ms", "auto_start", "sdo",
         "objects", "tpdos", "rpdos", "traffic", "pdop", "emcy", "loader"});
    if (auto name = in_.string(n, "name", path, false)) spec.name = *name;
    read_kind(n, path, r);
    read_node_id(n, path, r);
    read_device_type(n, path, r.kind, spec);
    read_identity(n, path, spec.identity);
    if (auto v = in_.integer(n, "heartbeat_ms", path, 0, 65535)) {
      spec.heartbeat_ms = static_cast<std::uint16_t>(*v);
    }
    // seeds/002: a MicroCANopen network has no NMT master, so its nodes start themselves.
    spec.auto_start = r.kind == NodeKind::microcanopen;
    if (auto v = in_.boolean(n, "auto_start", path)) spec.auto_start = *v;
    read_sdo(n, path, r.kind, spec);
    read_behaviour(n, path, r);
    return r;
  }

  // Objects first: PDO maps and traffic are checked against what the node declares.
  void read_behaviour(const YAML::Node& n, const std::string& path, NodeRead& r) {
    NodeSpec& spec = r.spec;
    ObjectTable objects;
    read_objects(n, path, r.kind, spec, objects);
    // 1001h is always present and mappable (a TPDO may carry the error register).
    objects.emplace(object_key(0x1001, 0), DeclaredObject{DataType::unsigned8, Access::ro, 1, 0});

    std::map<unsigned, DeclaredPdo> tpdos;
    std::map<unsigned, DeclaredPdo> rpdos;
    read_pdos(n, path, true, r, objects, tpdos);
    read_pdos(n, path, false, r, objects, rpdos);
    const bool pdop_ok = read_pdop(n, path, r.kind, spec.pdop);
    read_emcy(n, path, r.kind, spec.emcy);
    read_loader(n, path, r.kind, spec.loader);
    read_traffic(n, path, r.kind, objects, tpdos, pdop_ok, spec);
  }

  void read_kind(const YAML::Node& n, const std::string& path, NodeRead& r) {
    auto kind = in_.string(n, "kind", path, true);
    if (!kind) return;
    r.kind = parse_node_kind(*kind);
    if (!r.kind) {
      in_.problem(n["kind"], path + ".kind",
                  "'" + *kind + "' is not a node kind: microcanopen, qd, fpga or cia301");
    } else {
      r.spec.kind = *r.kind;
    }
  }

  // qd and fpga nodes borrow the identifiers of nodes N+32.., so their own ids stop at 31.
  void read_node_id(const YAML::Node& n, const std::string& path, NodeRead& r) {
    const bool short_ids = r.kind == NodeKind::qd || r.kind == NodeKind::fpga;
    const YAML::Node node_id = n["node_id"];
    r.node_id_line = line_of(node_id);
    if (!node_id) {
      in_.problem(n, path + ".node_id", "missing (required)");
      return;
    }
    auto id = in_.integer_text(node_id, path + ".node_id");
    if (!id) return;
    const int max = short_ids ? kMaxShortNodeId : canopen::kMaxNodeId;
    if (!id->fits(1, static_cast<std::uint64_t>(max))) {
      in_.problem(node_id, path + ".node_id",
                  node_id.Scalar() + " is out of range 1.." + std::to_string(max) +
                      (short_ids ? std::string(": ") + to_string(*r.kind) +
                                       " nodes use ids 1..31 (their identifiers borrow those "
                                       "of nodes 33..127)"
                                 : ""));
      return;
    }
    r.node_id = static_cast<int>(id->magnitude);
    r.spec.node_id = static_cast<canopen::NodeId>(id->magnitude);
  }

  void read_device_type(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                        NodeSpec& spec) {
    auto v = in_.integer(n, "device_type", path, 0, 0xFFFFFFFF);
    if (!v) return;
    if (kind == NodeKind::qd && (*v & 0xFFFF) != 0) {
      in_.problem(n["device_type"], path + ".device_type",
                  "a qd node has a manufacturer device profile: profile number 0 in the low 16 "
                  "bits, the profile version in the high 16 (seeds/003), e.g. 0x00010000");
      return;
    }
    spec.device_type = static_cast<std::uint32_t>(*v);
  }

  void read_identity(const YAML::Node& n, const std::string& path, Identity& out) {
    const YAML::Node id = n["identity"];
    const std::string p = path + ".identity";
    if (!id || !in_.mapping(id, p)) return;
    in_.only_keys(id, p, {"vendor_id", "product_code", "revision", "serial"});
    if (auto v = in_.integer(id, "vendor_id", p, 0, 0xFFFFFFFF)) {
      out.vendor_id = static_cast<std::uint32_t>(*v);
    }
    if (auto v = in_.integer(id, "product_code", p, 0, 0xFFFFFFFF)) {
      out.product_code = static_cast<std::uint32_t>(*v);
    }
    if (auto v = in_.integer(id, "revision", p, 0, 0xFFFFFFFF)) {
      out.revision = static_cast<std::uint32_t>(*v);
    }
    if (auto v = in_.integer(id, "serial", p, 0, 0xFFFFFFFF)) {
      out.serial = static_cast<std::uint32_t>(*v);
    }
  }

  void read_sdo(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                NodeSpec& out) {
    const YAML::Node sdo = n["sdo"];
    const std::string p = path + ".sdo";
    if (!sdo) return;
    if (kind == NodeKind::fpga || kind == NodeKind::microcanopen) {
      in_.problem(sdo, p,
                  std::string(to_string(*kind)) +
                      " nodes serve expedited SDO only: there is no segmented or block transfer "
                      "to time out or size");
      return;
    }
    if (!in_.mapping(sdo, p)) return;
    in_.only_keys(sdo, p, {"timeout_ms", "block_size"});
    if (auto v = in_.integer(sdo, "timeout_ms", p, 1, 600000)) {
      out.sdo_timeout = std::chrono::milliseconds(*v);
    }
    if (auto v = in_.integer(sdo, "block_size", p, 1, 127)) {
      out.sdo_block_size = static_cast<std::uint8_t>(*v);
    }
  }

  void read_objects(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                    NodeSpec& spec, ObjectTable& table) {
    auto objects = in_.list(n, "objects", path);
    if (!objects) return;
    for (std::size_t i = 0; i < objects->size(); ++i) {
      const YAML::Node o = (*objects)[i];
      const std::string p = item_path(path, "objects", i);
      if (!o.IsMap()) {
        in_.problem(o, p, "must be a mapping with index, type and value");
        continue;
      }
      read_object(o, p, kind, spec, table);
    }
  }

  // An object with a bad type or value is still declared in `table` (when its place is valid) so
  // PDO maps that name it are not also reported as naming a missing object.
  void read_object(const YAML::Node& o, const std::string& p, std::optional<NodeKind> kind,
                   NodeSpec& spec, ObjectTable& table) {
    in_.only_keys(o, p, {"index", "sub", "type", "access", "value", "size"});
    auto index = in_.integer(o, "index", p, 0, 0xFFFF, true);
    std::int64_t sub = 0;
    bool sub_ok = true;
    if (o["sub"]) {
      // Sub-index FFh describes the object's structure; it never holds a value.
      auto s = in_.integer(o, "sub", p, 0, 254);
      sub_ok = s.has_value();
      if (s) sub = *s;
    }
    const std::optional<DataType> type = read_object_type(o, p);
    const Access access = read_access(o, p);
    bool placed = index.has_value() && sub_ok;
    if (index && !index_allowed(o, p, *index, kind)) placed = false;
    std::optional<std::vector<std::uint8_t>> value;
    if (type) value = read_value(o, p, *type);
    if (type && value) check_kind_size(o, p, kind, *type, value->size());
    if (!placed) return;
    const auto idx = static_cast<std::uint16_t>(*index);
    const auto sx = static_cast<std::uint8_t>(sub);
    const std::size_t bytes = value ? value->size() : type ? fixed_size(*type) : 0;
    auto [it, fresh] = table.emplace(object_key(idx, sx),
                                     DeclaredObject{type, access, bytes, line_of(o["index"])});
    if (!fresh) {
      in_.problem(
          o["index"], p + ".index",
          object_name(idx, sx) + " is already defined at line " + std::to_string(it->second.line));
      return;
    }
    if (type && value) spec.objects.push_back({idx, sx, *type, access, std::move(*value)});
  }

  std::optional<DataType> read_object_type(const YAML::Node& o, const std::string& p) {
    auto t = in_.string(o, "type", p, true);
    if (!t) return std::nullopt;
    auto type = parse_data_type(*t);
    if (!type) {
      in_.problem(o["type"], p + ".type",
                  "'" + *t +
                      "' is not a data type: boolean, integer8..64, unsigned8..64, real32, "
                      "real64, visible_string, octet_string or domain");
    }
    return type;
  }

  // Read-write unless told otherwise (also after a refused access, which is reported).
  Access read_access(const YAML::Node& o, const std::string& p) {
    static const std::map<std::string, Access> kAccess = {
        {"ro", Access::ro}, {"wo", Access::wo}, {"rw", Access::rw}, {"const", Access::constant}};
    auto a = in_.string(o, "access", p, false);
    if (!a) return Access::rw;
    if (auto it = kAccess.find(*a); it != kAccess.end()) return it->second;
    in_.problem(o["access"], p + ".access", "'" + *a + "' is not ro, wo, rw or const");
    return Access::rw;
  }

  // False (reported) for an index the node builds itself or that its kind cannot hold.
  bool index_allowed(const YAML::Node& o, const std::string& p, std::int64_t index,
                     std::optional<NodeKind> kind) {
    const auto idx = static_cast<std::uint16_t>(index);
    if (auto owner = owner_of(idx, kind)) {
      in_.problem(o["index"], p + ".index", "refused: " + *owner);
      return false;
    }
    if (kind == NodeKind::microcanopen && (idx < 0x2000 || idx > 0x9FFF)) {
      in_.problem(o["index"], p + ".index",
                  "microcanopen nodes have only 1000h, 1001h and 1018h plus process data "
                  "(seeds/002): give process objects 2000h-9FFFh");
      return false;
    }
    return true;
  }

  // Expedited-only nodes (fpga, microcanopen) cannot move more than 4 bytes in one SDO, and a
  // MicroCANopen variable is 1 to 4 bytes of number (seeds/002).
  void check_kind_size(const YAML::Node& o, const std::string& p, std::optional<NodeKind> kind,
                       DataType type, std::size_t bytes) {
    if (kind == NodeKind::microcanopen && (is_variable_length(type) || fixed_size(type) > 4)) {
      in_.problem(o["type"], p + ".type",
                  std::string(to_string(type)) +
                      ": a microcanopen process variable is a number of 1 to 4 bytes (seeds/002)");
    } else if (kind == NodeKind::fpga && bytes > 4) {
      in_.problem(o["type"], p + ".type",
                  std::string(to_string(type)) + " of " + std::to_string(bytes) +
                      " bytes: fpga nodes serve expedited SDO only, at most 4 bytes per object "
                      "(stream big data as PDO Packets instead)");
    }
  }

  using Bytes = std::vector<std::uint8_t>;

  // An object's initial value: from `value`, or `size` zero bytes (octet_string and domain), or
  // all zeros when neither is given.
  std::optional<Bytes> read_value(const YAML::Node& o, const std::string& p, DataType type) {
    const YAML::Node value = o["value"];
    const YAML::Node size = o["size"];
    if (value && size) {
      in_.problem(size, p + ".size", "give value or size, not both");
      return std::nullopt;
    }
    if (size) return read_zero_filled(size, p + ".size", type);
    if (!value) return Bytes(fixed_size(type), 0);
    const std::string vfield = p + ".value";
    if (type == DataType::octet_string || type == DataType::domain) {
      return read_byte_list(value, vfield);
    }
    if (!value.IsScalar()) {
      in_.problem(value, vfield,
                  type == DataType::visible_string
                      ? "must be a string"
                      : std::string("must be a number for ") + to_string(type));
      return std::nullopt;
    }
    switch (type) {
      case DataType::visible_string:
        return read_string_value(value, vfield);
      case DataType::boolean:
        return read_boolean_value(value, vfield);
      case DataType::real32:
      case DataType::real64:
        return read_real_value(value, vfield, type);
      default:
        return read_integer_value(value, vfield, type);
    }
  }

  std::optional<Bytes> read_zero_filled(const YAML::Node& size, const std::string& field,
                                        DataType type) {
    if (type != DataType::octet_string && type != DataType::domain) {
      in_.problem(size, field,
                  "only octet_string and domain objects take a size (a zero-filled value)");
      return std::nullopt;
    }
    auto v = in_.integer(size, field, 0, static_cast<std::int64_t>(kMaxVariableBytes));
    if (!v) return std::nullopt;
    return Bytes(static_cast<std::size_t>(*v), 0);
  }

  // octet_string and domain values are written as a list of bytes; every bad byte is reported.
  std::optional<Bytes> read_byte_list(const YAML::Node& value, const std::string& vfield) {
    if (!value.IsSequence()) {
      in_.problem(value, vfield, "must be a list of byte values, e.g. [0x01, 0x02]");
      return std::nullopt;
    }
    Bytes bytes;
    bool ok = true;
    for (std::size_t k = 0; k < value.size(); ++k) {
      auto b = in_.integer(value[k], vfield + "[" + std::to_string(k) + "]", 0, 255);
      ok = ok && b.has_value();
      if (b) bytes.push_back(static_cast<std::uint8_t>(*b));
    }
    if (!ok) return std::nullopt;
    return bytes;
  }

  std::optional<Bytes> read_string_value(const YAML::Node& value, const std::string& vfield) {
    const std::string& text = value.Scalar();
    if (text.size() > kMaxVariableBytes) {
      in_.problem(value, vfield, "longer than " + std::to_string(kMaxVariableBytes) + " bytes");
      return std::nullopt;
    }
    return Bytes(text.begin(), text.end());
  }

  // YAML's booleans plus 0 and 1, as EDS files write them.
  std::optional<Bytes> read_boolean_value(const YAML::Node& value, const std::string& vfield) {
    const std::string& text = value.Scalar();
    bool b = false;
    if (YAML::convert<bool>::decode(value, b) || text == "0" || text == "1") {
      return Bytes(1, b || text == "1" ? 1 : 0);
    }
    in_.problem(value, vfield, "'" + text + "' is not a boolean: true, false, 0 or 1");
    return std::nullopt;
  }

  // Infinities and NaN are kept (a node may publish them); a finite real32 must not overflow.
  std::optional<Bytes> read_real_value(const YAML::Node& value, const std::string& vfield,
                                       DataType type) {
    const std::string& text = value.Scalar();
    auto d = parse_real(text);
    if (!d) {
      in_.problem(value, vfield, "'" + text + "' is not a number");
      return std::nullopt;
    }
    if (type == DataType::real64) return le(std::bit_cast<std::uint64_t>(*d), 8);
    if (std::isfinite(*d) && std::fabs(*d) > std::numeric_limits<float>::max()) {
      in_.problem(value, vfield, text + " does not fit real32");
      return std::nullopt;
    }
    return le(std::bit_cast<std::uint32_t>(static_cast<float>(*d)), 4);
  }

  // Range errors name the type's range, in hex when the value was written in hex.
  std::optional<Bytes> read_integer_value(const YAML::Node& value, const std::string& vfield,
                                          DataType type) {
    const std::string& text = value.Scalar();
    auto v = parse_integer(text);
    if (!v) {
      in_.problem(value, vfield, "'" + text + "' is not an integer (decimal or 0x hex)");
      return std::nullopt;
    }
    const std::size_t n = fixed_size(type);
    const unsigned bits = static_cast<unsigned>(8 * n);
    if (is_unsigned_integer(type)) {
      const std::uint64_t max = bits == 64 ? ~std::uint64_t{0} : (std::uint64_t{1} << bits) - 1;
      if (v->negative) {
        in_.problem(
            value, vfield,
            "negative values are only for integer types, not " + std::string(to_string(type)));
        return std::nullopt;
      }
      if (!v->fits(0, max)) {
        in_.problem(value, vfield,
                    text + " does not fit " + to_string(type) + " (0.." +
                        (v->hex ? hex(max, static_cast<int>(2 * n)) : std::to_string(max)) + ")");
        return std::nullopt;
      }
      return le(v->bits(), n);
    }
    if (is_signed_integer(type)) {
      const std::int64_t max = static_cast<std::int64_t>((std::uint64_t{1} << (bits - 1)) - 1);
      const std::int64_t min = -max - 1;
      if (!v->fits(min, static_cast<std::uint64_t>(max))) {
        in_.problem(value, vfield,
                    text + " does not fit " + to_string(type) + " (" + std::to_string(min) + ".." +
                        std::to_string(max) + ")");
        return std::nullopt;
      }
      return le(v->bits(), n);
    }
    return std::nullopt;  // every type is handled above
  }

  void read_pdos(const YAML::Node& n, const std::string& path, bool transmit, NodeRead& r,
                 const ObjectTable& objects, std::map<unsigned, DeclaredPdo>& declared) {
    const char* key = transmit ? "tpdos" : "rpdos";
    auto pdos = in_.list(n, key, path);
    if (!pdos) return;
    for (std::size_t i = 0; i < pdos->size(); ++i) {
      const YAML::Node d = (*pdos)[i];
      const std::string p = item_path(path, key, i);
      if (!d.IsMap()) {
        in_.problem(d, p, "must be a mapping with number and map");
        continue;
      }
      read_pdo(d, p, transmit, r, objects, declared);
    }
  }

  void read_pdo(const YAML::Node& d, const std::string& p, bool transmit, NodeRead& r,
                const ObjectTable& objects, std::map<unsigned, DeclaredPdo>& declared) {
    const auto kind = r.kind;
    check_pdo_keys(d, p, transmit);
    PdoSpec pdo;
    // A PDO without a valid, unique number is still read through, so all its problems show.
    const bool numbered = claim_pdo_number(d, p, transmit, kind, declared, pdo);
    if (const YAML::Node cob = d["cob_id"]) {
      read_cob_id(cob, p + ".cob_id", transmit, kind, pdo);
      if (pdo.cob_id && transmit && numbered) {
        r.explicit_tpdos.push_back({*pdo.cob_id, pdo.number, cob, p + ".cob_id"});
      }
    }
    if (auto v = in_.boolean(d, "enabled", p)) pdo.enabled = *v;
    if (numbered) declared[pdo.number].enabled = pdo.enabled;
    read_transmission(d, p, transmit, kind, pdo);
    if (transmit) {
      if (auto v = in_.integer(d, "inhibit_100us", p, 0, 65535)) {
        pdo.inhibit_100us = static_cast<std::uint16_t>(*v);
      }
      if (auto v = in_.integer(d, "event_ms", p, 0, 65535)) {
        pdo.event_timer_ms = static_cast<std::uint16_t>(*v);
      }
    }
    read_mapping(d, p, transmit, objects, pdo);
    if (numbered) (transmit ? r.spec.tpdos : r.spec.rpdos).push_back(std::move(pdo));
  }

  // The timer keys exist for TPDOs only; on an RPDO they get a reason, not "unknown key".
  void check_pdo_keys(const YAML::Node& d, const std::string& p, bool transmit) {
    if (!transmit) {
      for (const char* tx_only : {"inhibit_100us", "event_ms"}) {
        if (d[tx_only]) in_.problem(d[tx_only], p + "." + tx_only, "applies to TPDOs only");
      }
    }
    in_.only_keys(
        d, p, {"number", "cob_id", "enabled", "transmission", "inhibit_100us", "event_ms", "map"});
  }

  // Reads the PDO's number into `pdo` and records it in `declared`; false when it is missing,
  // out of range for the node's kind, or already taken.
  bool claim_pdo_number(const YAML::Node& d, const std::string& p, bool transmit,
                        std::optional<NodeKind> kind, std::map<unsigned, DeclaredPdo>& declared,
                        PdoSpec& pdo) {
    const YAML::Node number_at = d["number"];
    if (!number_at) {
      in_.problem(d, p + ".number", "missing (required)");
      return false;
    }
    auto v = in_.integer_text(number_at, p + ".number");
    if (!v) return false;
    const int max_number =
        transmit && (kind == NodeKind::qd || !kind) ? kMaxQdTpdos : kMaxStandardPdos;
    if (!v->fits(1, static_cast<std::uint64_t>(max_number))) {
      in_.problem(number_at, p + ".number",
                  number_at.Scalar() + " is out of range 1.." + std::to_string(max_number) +
                      pdo_numbers_of(transmit, kind));
      return false;
    }
    pdo.number = static_cast<unsigned>(v->magnitude);
    auto [it, fresh] = declared.emplace(pdo.number, DeclaredPdo{true, line_of(number_at)});
    if (!fresh) {
      in_.problem(number_at, p + ".number",
                  std::string(transmit ? "TPDO" : "RPDO") + " " + std::to_string(pdo.number) +
                      " is already defined at line " + std::to_string(it->second.line));
      return false;
    }
    return true;
  }

  // Why the PDO numbers end where they do, for the out-of-range message.
  static std::string pdo_numbers_of(bool transmit, std::optional<NodeKind> kind) {
    if (transmit && kind == NodeKind::qd) {
      return ": a qd node has 34 TPDOs (extended connection set, seeds/003)";
    }
    if (transmit) {
      return std::string(": ") + (kind ? to_string(*kind) : "this") +
             " nodes have TPDOs 1..4; only qd nodes have 34";
    }
    return ": every kind has RPDOs 1..4";
  }

  void read_cob_id(const YAML::Node& cob, const std::string& field, bool transmit,
                   std::optional<NodeKind> kind, PdoSpec& pdo) {
    if (kind == NodeKind::fpga) {
      in_.problem(cob, field,
                  "fpga PDOs are fixed: 4 TPDOs and 4 RPDOs at the predefined COB-IDs, the "
                  "FPGA's message filter is hard-wired (seeds/000); remove cob_id");
      return;
    }
    if (kind == NodeKind::qd) {
      in_.problem(cob, field,
                  "qd PDOs have fixed COB-IDs from the extended connection set (seeds/003: "
                  "COB-IDs are not changed, only enabled); remove cob_id");
      return;
    }
    if (kind == NodeKind::microcanopen && transmit) {
      in_.problem(cob, field,
                  "microcanopen TPDOs transmit on the predefined connection set (seeds/002 "
                  "table 3); only RPDO COB-IDs can be changed");
      return;
    }
    auto v = in_.integer(cob, field, 0, 0x7FF);
    if (!v) return;
    const auto id = static_cast<std::uint32_t>(*v);
    if (restricted_cob_id(id)) {
      in_.problem(
          cob, field,
          hex(id, 3) + " is restricted by CiA 301 (NMT, SDO, NMT error control, LSS or reserved)");
      return;
    }
    pdo.cob_id = id;
  }

  void read_transmission(const YAML::Node& d, const std::string& p, bool transmit,
                         std::optional<NodeKind> kind, PdoSpec& pdo) {
    const YAML::Node t = d["transmission"];
    if (!t) return;
    auto v = in_.integer(t, p + ".transmission", 0, 255);
    if (!v) return;
    if (*v > 240 && *v < 254) {
      in_.problem(t, p + ".transmission",
                  std::to_string(*v) +
                      " is not simulated: 0 (acyclic synchronous), 1..240 (every n-th SYNC), "
                      "254 or 255 (event-driven); 241..251 are reserved and remote-request "
                      "PDOs (252, 253) are not supported");
      return;
    }
    if (kind == NodeKind::microcanopen && transmit && *v < 254) {
      in_.problem(t, p + ".transmission",
                  "microcanopen TPDOs are event-driven only, 254 or 255: timer and change of "
                  "state, no SYNC (seeds/002)");
      return;
    }
    pdo.transmission_type = static_cast<std::uint8_t>(*v);
  }

  // One entry of a PDO map as written, before it is checked against the node's objects.
  struct MapEntry {
    std::optional<ObjectRef> ref;
    std::optional<std::int64_t> bits;  // absent: the whole object
    bool bits_ok = true;               // false: a length was given but refused
  };

  // map: ["6000:01/16", ...] or [{index: 0x6000, sub: 1, bits: 16}, ...]; bits default to the
  // whole object.
  void read_mapping(const YAML::Node& d, const std::string& p, bool transmit,
                    const ObjectTable& objects, PdoSpec& pdo) {
    auto map = in_.list(d, "map", p);
    if (!map) return;
    int total = 0;
    // The 64-bit total is only checked when every length is known, so one bad entry does not
    // also raise a misleading total.
    bool all_known = true;
    for (std::size_t k = 0; k < map->size(); ++k) {
      const YAML::Node e = (*map)[k];
      const std::string f = p + ".map[" + std::to_string(k) + "]";
      const MapEntry entry = read_map_entry(e, f);
      all_known = all_known && entry.bits_ok;
      if (!entry.ref) {
        all_known = false;
        continue;
      }
      const auto length = mapped_length(e, f, transmit, objects, *entry.ref, entry.bits);
      if (!length) {
        all_known = false;
        continue;
      }
      total += static_cast<int>(*length);
      pdo.mapping.push_back(
          {entry.ref->first, entry.ref->second, static_cast<std::uint8_t>(*length)});
    }
    if (all_known && total > kMaxPdoBits) {
      in_.problem(*map, p + ".map",
                  std::to_string(total) + " bits mapped: a PDO carries at most 64 bits");
    }
  }

  MapEntry read_map_entry(const YAML::Node& e, const std::string& f) {
    if (e.IsMap()) return read_map_entry_fields(e, f);
    if (e.IsScalar()) return read_map_entry_text(e, f);
    in_.problem(e, f, "must be \"index:sub/bits\" or {index, sub, bits}");
    return {};
  }

  // {index: 0x6000, sub: 1, bits: 16}
  MapEntry read_map_entry_fields(const YAML::Node& e, const std::string& f) {
    MapEntry entry;
    in_.only_keys(e, f, {"index", "sub", "bits"});
    auto index = in_.integer(e, "index", f, 0, 0xFFFF, true);
    auto sub = e["sub"] ? in_.integer(e, "sub", f, 0, 254) : std::optional<std::int64_t>(0);
    if (index && sub) {
      entry.ref = std::pair{static_cast<std::uint16_t>(*index), static_cast<std::uint8_t>(*sub)};
    }
    if (e["bits"]) {
      entry.bits = in_.integer(e, "bits", f, 0, 255);
      entry.bits_ok = entry.bits.has_value();
    }
    return entry;
  }

  // "6000:01/16": the length after the slash is decimal bits, as in CiA 301 mappings.
  MapEntry read_map_entry_text(const YAML::Node& e, const std::string& f) {
    MapEntry entry;
    const std::string& s = e.Scalar();
    const auto slash = s.find('/');
    if (slash == std::string::npos) {
      entry.ref = in_.object_ref(e, f);
      return entry;
    }
    const std::string ref_text = s.substr(0, slash);
    const std::string bits_text = s.substr(slash + 1);
    auto v = parse_integer(bits_text);
    if (!v || v->negative || v->hex || !v->fits(0, 255)) {
      in_.problem(e, f, "'" + bits_text + "' after the slash must be a length in bits");
      entry.bits_ok = false;
    } else {
      entry.bits = static_cast<std::int64_t>(v->magnitude);
    }
    entry.ref = parse_object_ref(ref_text);
    if (!entry.ref) {
      in_.problem(e, f, "must be index:sub/bits in hex:hex/decimal, e.g. \"6000:01/16\"");
    }
    return entry;
  }

  // The length in bits the entry maps, once the object exists on this node, may be accessed in
  // this direction (reported, not fatal) and holds that many bits; nullopt when it cannot be
  // mapped or its size is unknown (its own problem is reported where it is declared).
  std::optional<std::int64_t> mapped_length(const YAML::Node& e, const std::string& f,
                                            bool transmit, const ObjectTable& objects,
                                            ObjectRef ref, std::optional<std::int64_t> bits) {
    const std::string name = object_name(ref.first, ref.second);
    auto it = objects.find(object_key(ref.first, ref.second));
    if (it == objects.end()) {
      in_.problem(e, f,
                  name +
                      " is not an object of this node: define it in objects (1001h is the "
                      "only built-in object a PDO may map)");
      return std::nullopt;
    }
    const DeclaredObject& obj = it->second;
    if (transmit && obj.access == Access::wo) {
      in_.problem(e, f, name + " is write-only: a TPDO can only map readable objects");
    }
    if (!transmit && (obj.access == Access::ro || obj.access == Access::constant)) {
      in_.problem(e, f, name + " is read-only: an RPDO can only map writable objects");
    }
    if (!obj.type || obj.bytes == 0) return std::nullopt;
    const auto object_bits = static_cast<std::int64_t>(8 * obj.bytes);
    const std::int64_t length = bits.value_or(object_bits);
    if (length == 0 || length % 8 != 0 || length > kMaxPdoBits) {
      in_.problem(
          e, f, std::to_string(length) + " bits: a mapped length is a multiple of 8, from 8 to 64");
      return std::nullopt;
    }
    if (length > object_bits) {
      in_.problem(e, f,
                  std::to_string(length) + " bits is more than " + name + " holds (" +
                      std::to_string(object_bits) + " bits)");
      return std::nullopt;
    }
    return length;
  }

  // Returns false when the section was refused, so traffic does not also check against it.
  bool read_pdop(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                 PdopSpec& out) {
    const YAML::Node pdop = n["pdop"];
    const std::string p = path + ".pdop";
    if (!pdop) return true;
    if (kind && kind != NodeKind::fpga) {
      in_.problem(pdop, p, "only fpga nodes speak PDO Packets (seeds/000)");
      return false;
    }
    if (!in_.mapping(pdop, p)) return false;
    in_.only_keys(pdop, p, {"max_packet_bytes", "fragment_timeout_ms", "window"});
    bool ok = true;
    if (pdop["max_packet_bytes"]) {
      auto v = in_.integer(pdop, "max_packet_bytes", p, 1,
                           static_cast<std::int64_t>(kMaxPdopPacketBytes));
      ok = v.has_value();
      if (v) out.max_packet_bytes = static_cast<std::size_t>(*v);
    }
    if (auto v = in_.integer(pdop, "fragment_timeout_ms", p, 1, 10000)) {
      out.fragment_timeout = std::chrono::milliseconds(*v);
    }
    if (auto v = in_.integer(pdop, "window", p, 1, 255)) {
      out.window = static_cast<std::uint8_t>(*v);
    }
    return ok;
  }

  void read_emcy(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                 EmcySpec& out) {
    const YAML::Node emcy = n["emcy"];
    const std::string p = path + ".emcy";
    if (!emcy || !in_.mapping(emcy, p)) return;
    in_.only_keys(emcy, p, {"inhibit_100us", "holdoff_ms"});
    if (auto v = in_.integer(emcy, "inhibit_100us", p, 0, 65535)) {
      out.inhibit_100us = static_cast<std::uint16_t>(*v);
    }
    if (const YAML::Node h = emcy["holdoff_ms"]) {
      if (kind && kind != NodeKind::qd) {
        in_.problem(h, p + ".holdoff_ms",
                    "only qd nodes send state-change EMCYs, which the hold-off paces (seeds/003)");
      } else if (auto v = in_.integer(h, p + ".holdoff_ms", 0, 60000)) {
        out.holdoff = std::chrono::milliseconds(*v);
      }
    }
  }

  void read_loader(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                   LoaderSpec& out) {
    const YAML::Node loader = n["loader"];
    const std::string p = path + ".loader";
    if (!loader) return;
    if (kind && kind != NodeKind::qd) {
      in_.problem(loader, p, "only qd nodes have the CANopen loader (seeds/003)");
      return;
    }
    if (!in_.mapping(loader, p)) return;
    in_.only_keys(loader, p, {"application_valid", "wait_for_command"});
    if (auto v = in_.boolean(loader, "application_valid", p)) out.application_valid = *v;
    if (auto v = in_.boolean(loader, "wait_for_command", p)) out.wait_for_command = *v;
  }

  // What a traffic entry is checked against: the node's kind and what it declared before.
  struct TrafficContext {
    std::optional<NodeKind> kind;
    const ObjectTable& objects;
    const std::map<unsigned, DeclaredPdo>& tpdos;
    bool tpdos_known;  // false: tpdos was refused, so a missing TPDO is not reported twice
    bool pdop_ok;
  };

  void read_traffic(const YAML::Node& n, const std::string& path, std::optional<NodeKind> kind,
                    const ObjectTable& objects, const std::map<unsigned, DeclaredPdo>& tpdos,
                    bool pdop_ok, NodeSpec& spec) {
    auto traffic = in_.list(n, "traffic", path);
    if (!traffic) return;
    const TrafficContext context{kind, objects, tpdos, !n["tpdos"] || n["tpdos"].IsSequence(),
                                 pdop_ok};
    for (std::size_t i = 0; i < traffic->size(); ++i) {
      const YAML::Node t = (*traffic)[i];
      const std::string p = item_path(path, "traffic", i);
      if (!t.IsMap()) {
        in_.problem(t, p, "must be a mapping with kind and period_ms");
        continue;
      }
      TrafficSpec out;
      if (read_traffic_entry(t, p, context, spec.pdop, out)) spec.traffic.push_back(out);
    }
  }

  // Every field is read even after a problem, so one pass reports them all.
  bool read_traffic_entry(const YAML::Node& t, const std::string& p, const TrafficContext& context,
                          const PdopSpec& pdop, TrafficSpec& out) {
    const std::optional<TrafficSpec::Kind> tk = read_traffic_kind(t, p);
    bool ok = tk.has_value();
    if (auto v = in_.integer(t, "period_ms", p, 1, 3600000, true)) {
      out.period = std::chrono::milliseconds(*v);
    } else {
      ok = false;
    }
    if (!tk) {
      in_.only_keys(t, p, {"kind", "period_ms", "object", "step", "pdo", "bytes", "subsystem"});
      return false;
    }
    out.kind = *tk;
    switch (*tk) {
      case TrafficSpec::Kind::counter:
        in_.only_keys(t, p, {"kind", "period_ms", "object", "step"});
        return read_counter(t, p, context.objects, out) && ok;
      case TrafficSpec::Kind::pdop_sample:
        in_.only_keys(t, p, {"kind", "period_ms", "pdo", "bytes"});
        if (context.kind && context.kind != NodeKind::fpga) {
          in_.problem(t["kind"], p + ".kind",
                      "pdop_sample is for fpga nodes, the ones that send PDO Packets "
                      "(seeds/000)");
          return false;
        }
        return read_pdop_sample(t, p, context.tpdos, context.tpdos_known, context.pdop_ok, pdop,
                                out) &&
               ok;
      case TrafficSpec::Kind::subsystem_event:
        in_.only_keys(t, p, {"kind", "period_ms", "subsystem"});
        return read_subsystem_event(t, p, context.kind, out) && ok;
    }
    return false;  // every kind is handled above
  }

  std::optional<TrafficSpec::Kind> read_traffic_kind(const YAML::Node& t, const std::string& p) {
    static const std::map<std::string, TrafficSpec::Kind> kTrafficKinds = {
        {"counter", TrafficSpec::Kind::counter},
        {"pdop_sample", TrafficSpec::Kind::pdop_sample},
        {"subsystem_event", TrafficSpec::Kind::subsystem_event}};
    auto k = in_.string(t, "kind", p, true);
    if (!k) return std::nullopt;
    if (auto it = kTrafficKinds.find(*k); it != kTrafficKinds.end()) return it->second;
    in_.problem(t["kind"], p + ".kind",
                "'" + *k + "' is not a traffic kind: counter, pdop_sample or subsystem_event");
    return std::nullopt;
  }

  bool read_subsystem_event(const YAML::Node& t, const std::string& p, std::optional<NodeKind> kind,
                            TrafficSpec& out) {
    if (kind && kind != NodeKind::qd) {
      in_.problem(t["kind"], p + ".kind",
                  "subsystem_event is for qd nodes, whose EMCY codes F000h-FFFFh flag "
                  "subsystem state changes (seeds/003)");
      return false;
    }
    auto v = in_.integer(t, "subsystem", p, 0, 11, true);
    if (!v) return false;
    out.subsystem = static_cast<unsigned>(*v);
    return true;
  }

  bool read_counter(const YAML::Node& t, const std::string& p, const ObjectTable& objects,
                    TrafficSpec& out) {
    bool ok = true;
    const YAML::Node object = t["object"];
    if (!object) {
      in_.problem(t, p + ".object", "missing (required)");
      ok = false;
    } else if (auto ref = in_.object_ref(object, p + ".object")) {
      const std::string name = object_name(ref->first, ref->second);
      auto it = objects.find(object_key(ref->first, ref->second));
      if (it == objects.end() || it->second.line == 0) {
        in_.problem(object, p + ".object", name + " is not in this node's objects");
        ok = false;
      } else if (it->second.type && !is_signed_integer(*it->second.type) &&
                 !is_unsigned_integer(*it->second.type)) {
        in_.problem(object, p + ".object",
                    name + " is " + to_string(*it->second.type) +
                        ": a counter needs an integer or unsigned object");
        ok = false;
      } else if (it->second.access == Access::constant) {
        in_.problem(object, p + ".object", name + " is const: a counter must be able to change it");
        ok = false;
      }
      out.index = ref->first;
      out.sub = ref->second;
    } else {
      ok = false;
    }
    if (const YAML::Node step = t["step"]) {
      if (auto v = in_.integer_text(step, p + ".step")) {
        if (!v->fits(std::numeric_limits<std::int64_t>::min(),
                     std::numeric_limits<std::int64_t>::max())) {
          in_.problem(step, p + ".step", step.Scalar() + " does not fit 64 signed bits");
          ok = false;
        } else if (v->magnitude == 0) {
          in_.problem(step, p + ".step", "0 would never change the object");
          ok = false;
        } else {
          out.step = v->as_signed();
        }
      } else {
        ok = false;
      }
    }
    return ok;
  }

  bool read_pdop_sample(const YAML::Node& t, const std::string& p,
                        const std::map<unsigned, DeclaredPdo>& tpdos, bool tpdos_known,
                        bool pdop_ok, const PdopSpec& pdop, TrafficSpec& out) {
    bool ok = true;
    if (auto v = in_.integer(t, "pdo", p, 1, kMaxStandardPdos, true)) {
      out.pdo = static_cast<unsigned>(*v);
      auto it = tpdos.find(out.pdo);
      if (it == tpdos.end()) {
        if (tpdos_known) {
          in_.problem(t["pdo"], p + ".pdo",
                      "TPDO " + std::to_string(out.pdo) + " is not in this node's tpdos");
        }
        ok = false;
      } else if (!it->second.enabled) {
        in_.problem(t["pdo"], p + ".pdo",
                    "TPDO " + std::to_string(out.pdo) + " is disabled (line " +
                        std::to_string(it->second.line) + ")");
        ok = false;
      }
    } else {
      ok = false;
    }
    if (const YAML::Node bytes = t["bytes"]) {
      const auto max =
          static_cast<std::int64_t>(pdop_ok ? pdop.max_packet_bytes : kMaxPdopPacketBytes);
      if (auto v = in_.integer_text(bytes, p + ".bytes")) {
        if (!v->fits(1, static_cast<std::uint64_t>(max))) {
          in_.problem(bytes, p + ".bytes",
                      bytes.Scalar() + " is out of range 1.." + std::to_string(max) +
                          " (pdop.max_packet_bytes)");
          ok = false;
        } else {
          out.bytes = static_cast<std::size_t>(v->magnitude);
        }
      } else {
        ok = false;
      }
    } else if (out.bytes > pdop.max_packet_bytes) {
      in_.problem(t, p + ".bytes",
                  "the default of " + std::to_string(out.bytes) +
                      " bytes is more than pdop.max_packet_bytes: give bytes");
      ok = false;
    }
    return ok;
  }

  Reader& in_;
};

}  // namespace

RigSpec parse_rig(std::string_view yaml, const std::string& file) {
  const YAML::Node root = config::parse_document(yaml, file);
  Reader in(file);
  RigSpec rig = RigReader(in).read(root);
  in.finish();
  return rig;
}

RigSpec load_rig(const std::string& path) {
  return parse_rig(config::read_config_file(path), path);
}

}  // namespace canbridge::sim
