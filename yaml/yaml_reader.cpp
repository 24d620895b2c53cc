#include "yaml/yaml_reader.hpp"

#include <fcntl.h>
#include <linux/limits.h>
#include <net/if.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <map>

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

static_assert(kMaxInterfaceNameBytes == IFNAMSIZ - 1);
static_assert(kMaxPathBytes == PATH_MAX - 1);

namespace {

const std::string kFileRule = "a configuration file must be a regular file of at most 1 MiB (" +
                              std::to_string(kMaxConfigFileBytes) + " bytes)";

[[noreturn]] void refuse_file(const std::string& path, const std::string& message) {
  throw ConfigError({{path, 0, "", message}});
}

const char* file_kind(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

void check_file_status(const std::string& path, const struct stat& status) {
  if (!S_ISREG(status.st_mode)) {
    refuse_file(path, std::string("is ") + file_kind(status.st_mode) + ": " + kFileRule);
  }
  if (static_cast<std::uint64_t>(status.st_size) > kMaxConfigFileBytes) {
    refuse_file(path, "is " + std::to_string(status.st_size) + " bytes: " + kFileRule);
  }
}

// Closes the descriptor however read_config_file leaves.
struct FileDescriptor {
  int fd;
  ~FileDescriptor() { ::close(fd); }
};

}  // namespace

std::string read_config_file(const std::string& path) {
  // Checked before the open too: opening a device can have effects of its own (a tape rewinds).
  struct stat status {};
  if (::stat(path.c_str(), &status) != 0) {
    refuse_file(path, std::string("cannot open the file: ") + std::strerror(errno));
  }
  check_file_status(path, status);
  // O_NONBLOCK: should the path have become a FIFO since, the open returns instead of waiting
  // for a writer; the fstat below then refuses it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) refuse_file(path, std::string("cannot open the file: ") + std::strerror(errno));
  const FileDescriptor closer{fd};
  if (::fstat(fd, &status) != 0) {
    refuse_file(path, std::string("cannot read the file: ") + std::strerror(errno));
  }
  check_file_status(path, status);
  // Read up to one byte beyond the bound: a file that grew since the fstat is refused, not cut
  // short. In chunks, into a string sized by what was read: the text is kept for the life of the
  // process (to tell a reload's changes), and a buffer sized for the bound would keep 1 MiB of
  // zeroed, resident memory in every role.
  std::string text;
  text.reserve(static_cast<std::size_t>(status.st_size));
  std::array<char, 16 * 1024> chunk;
  while (text.size() <= kMaxConfigFileBytes) {
    const std::size_t want = std::min(chunk.size(), kMaxConfigFileBytes + 1 - text.size());
    const ssize_t n = ::read(fd, chunk.data(), want);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) refuse_file(path, std::string("cannot read the file: ") + std::strerror(errno));
    if (n == 0) break;
    text.append(chunk.data(), static_cast<std::size_t>(n));
  }
  if (text.size() > kMaxConfigFileBytes) refuse_file(path, "grew while read: " + kFileRule);
  text.shrink_to_fit();
  return text;
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

std::optional<std::string> YamlReader::interface_name(const YAML::Node& map, const char* key,
                                                      const std::string& path, bool required) {
  auto name = string(map, key, path, required);
  if (!name) return std::nullopt;
  const std::string field = join_path(path, key);
  if (name->size() > kMaxInterfaceNameBytes) {
    problem(map[key], field,
            "'" + *name + "' is " + std::to_string(name->size()) +
                " bytes: SocketCAN interface names are at most " +
                std::to_string(kMaxInterfaceNameBytes) + " characters (IFNAMSIZ - 1)");
    return std::nullopt;
  }
  const bool bad_character = std::any_of(name->begin(), name->end(), [](char c) {
    return c == '/' || c == ':' || c == '\0' || std::isspace(static_cast<unsigned char>(c));
  });
  if (bad_character || *name == "." || *name == "..") {
    problem(map[key], field,
            "'" + *name +
                "' is no interface name the kernel takes (no '/', ':', space or NUL; not . or ..)");
    return std::nullopt;
  }
  return name;
}

std::optional<std::string> YamlReader::file_path(const YAML::Node& map, const char* key,
                                                 const std::string& path, bool required) {
  auto text = string(map, key, path, required);
  if (!text) return std::nullopt;
  const std::string field = join_path(path, key);
  if (text->size() > kMaxPathBytes) {
    problem(map[key], field,
            "is " + std::to_string(text->size()) + " bytes: paths are at most " +
                std::to_string(kMaxPathBytes) + " (PATH_MAX - 1)");
    return std::nullopt;
  }
  if (text->find('\0') != std::string::npos) {
    problem(map[key], field, "contains a NUL byte, which no path can hold");
    return std::nullopt;
  }
  return text;
}

void YamlReader::finish() const {
  if (!problems_.empty()) throw ConfigError(problems_);
}

}  // namespace canbridge::config
