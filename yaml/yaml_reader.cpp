#include "yaml/yaml_reader.hpp"

#include <charconv>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

namespace canbridge::config {

std::string join_path(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}
std::string item_path(const std::string& path, const char* key, std::size_t i) {
  return join_path(path, key) + "[" + std::to_string(i) + "]";
}

int line_of(const YAML::Node& node) {
  return node.IsDefined() && node.Mark().line >= 0 ? node.Mark().line + 1 : 0;
}

std::string hex(std::uint64_t value, int digits) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%0*llX", digits, static_cast<unsigned long long>(value));
  return buf;
}

bool Integer::fits(std::int64_t min, std::uint64_t max) const {
  if (overflow) return false;
  if (!negative)
    return magnitude <= max && (min <= 0 || magnitude >= static_cast<std::uint64_t>(min));
  if (min >= 0) return false;
  return magnitude <= static_cast<std::uint64_t>(-(min + 1)) + 1;
}

std::optional<Integer> parse_integer(std::string_view s) {
  Integer v;
  if (!s.empty() && (s[0] == '-' || s[0] == '+')) {
    v.negative = s[0] == '-';
    s.remove_prefix(1);
  }
  int base = 10;
  if (s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
    base = 16;
    v.hex = true;
    s.remove_prefix(2);
  }
  if (s.empty()) return std::nullopt;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v.magnitude, base);
  if (ptr != s.data() + s.size()) return std::nullopt;
  if (ec == std::errc::result_out_of_range) {
    v.overflow = true;
  } else if (ec != std::errc{}) {
    return std::nullopt;
  }
  if (v.magnitude == 0 && !v.overflow) v.negative = false;
  return v;
}

YAML::Node parse_document(std::string_view yaml, const std::string& file) {
  YAML::Node root;
  try {
    root = YAML::Load(std::string(yaml));
  } catch (const YAML::Exception& e) {
    throw ConfigError(
        {{file, e.mark.line >= 0 ? e.mark.line + 1 : 0, "", "YAML syntax error: " + e.msg}});
  }
  if (!root.IsMap()) throw ConfigError({{file, 0, "", "the file must be a YAML mapping"}});
  return root;
}

std::string read_config_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError({{path, 0, "", "cannot open the file"}});
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void YamlReader::problem(const YAML::Node& at, const std::string& field,
                         const std::string& message) {
  problem(line_of(at), field, message);
}
void YamlReader::problem(int line, const std::string& field, const std::string& message) {
  problems_.push_back({file_, line, field, message});
}

void YamlReader::only_keys(const YAML::Node& map, const std::string& path,
                           std::initializer_list<std::string_view> known) {
  if (!map.IsMap()) return;
  std::map<std::string, int> seen;
  for (const auto& kv : map) {
    const std::string key = kv.first.Scalar();
    const std::string field = join_path(path, key);
    bool ok = false;
    for (std::string_view k : known) ok = ok || key == k;
    if (!ok) problem(kv.first, field, "unknown key");
    if (auto [it, fresh] = seen.emplace(key, line_of(kv.first)); !fresh) {
      problem(kv.first, field, "given twice (first at line " + std::to_string(it->second) + ")");
    }
  }
}

bool YamlReader::mapping(const YAML::Node& node, const std::string& field) {
  if (node.IsMap()) return true;
  problem(node, field, "must be a mapping");
  return false;
}

std::optional<YAML::Node> YamlReader::list(const YAML::Node& map, const char* key,
                                           const std::string& path) {
  const YAML::Node node = map[key];
  if (!node) return std::nullopt;
  if (!node.IsSequence()) {
    problem(node, join_path(path, key), "must be a list");
    return std::nullopt;
  }
  return node;
}

std::optional<std::string> YamlReader::string(const YAML::Node& map, const char* key,
                                              const std::string& path, bool required) {
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

std::optional<Integer> YamlReader::integer_text(const YAML::Node& node, const std::string& field) {
  if (!node.IsScalar()) {
    problem(node, field, "must be an integer");
    return std::nullopt;
  }
  auto v = parse_integer(node.Scalar());
  if (!v) problem(node, field, "'" + node.Scalar() + "' is not an integer (decimal or 0x hex)");
  return v;
}

std::optional<std::int64_t> YamlReader::integer(const YAML::Node& node, const std::string& field,
                                                std::int64_t min, std::int64_t max) {
  auto v = integer_text(node, field);
  if (!v) return std::nullopt;
  if (!v->fits(min, static_cast<std::uint64_t>(max))) {
    const int digits = max > 0xFFFF ? 8 : max > 0xFF ? 4 : 2;
    problem(node, field,
            node.Scalar() + " is out of range " +
                (v->hex ? hex(static_cast<std::uint64_t>(min), digits) + ".." +
                              hex(static_cast<std::uint64_t>(max), digits)
                        : std::to_string(min) + ".." + std::to_string(max)));
    return std::nullopt;
  }
  return v->as_signed();
}

std::optional<std::int64_t> YamlReader::integer(const YAML::Node& map, const char* key,
                                                const std::string& path, std::int64_t min,
                                                std::int64_t max, bool required) {
  const YAML::Node node = map[key];
  if (!node) {
    if (required) problem(map, join_path(path, key), "missing (required)");
    return std::nullopt;
  }
  return integer(node, join_path(path, key), min, max);
}

std::optional<bool> YamlReader::boolean(const YAML::Node& map, const char* key,
                                        const std::string& path) {
  const YAML::Node node = map[key];
  if (!node) return std::nullopt;
  bool v = false;
  if (!node.IsScalar() || !YAML::convert<bool>::decode(node, v)) {
    problem(node, join_path(path, key), "must be true or false");
    return std::nullopt;
  }
  return v;
}

void YamlReader::finish() const {
  if (!problems_.empty()) throw ConfigError(problems_);
}

}  // namespace canbridge::config
