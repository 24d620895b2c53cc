// Reads YAML for startup configuration (role configs, rig files) while collecting every problem
// with file, line and dotted field, instead of stopping at the first one.
#pragma once

#include <yaml-cpp/yaml.h>

#include <cstdint>
#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "yaml/config_error.hpp"

namespace canbridge::config {

// "a.b", and "a.b[3]" for list items: the field names problems carry.
std::string join_path(const std::string& path, const std::string& key);
std::string item_path(const std::string& path, const char* key, std::size_t i);
// 1-based line of a node; 0 when it has none (absent nodes).
int line_of(const YAML::Node& node);
// "0x00FF" with `digits` hex digits.
std::string hex(std::uint64_t value, int digits);

// An integer as written: sign and magnitude, so that the whole of INTEGER64 and UNSIGNED64 can
// be checked without a wider type.
struct Integer {
  bool negative = false;
  std::uint64_t magnitude = 0;
  bool overflow = false;  // more than 64 bits of magnitude
  bool hex = false;       // written as 0x...: range messages answer in hex

  bool fits(std::int64_t min, std::uint64_t max) const;
  // Two's complement; only meaningful after fits().
  std::uint64_t bits() const { return negative ? ~magnitude + 1 : magnitude; }
  std::int64_t as_signed() const { return static_cast<std::int64_t>(bits()); }
};
// Decimal or 0x hexadecimal, with an optional sign.
std::optional<Integer> parse_integer(std::string_view s);

// The largest configuration file read. The biggest real one is a few KiB; without a bound, a
// path to /dev/zero or a huge file would be read until memory ran out.
inline constexpr std::size_t kMaxConfigFileBytes = std::size_t{1} << 20;
// The longest SocketCAN interface name: IFNAMSIZ less its terminating NUL.
inline constexpr std::size_t kMaxInterfaceNameBytes = 15;
// The longest filesystem path: PATH_MAX less its terminating NUL.
inline constexpr std::size_t kMaxPathBytes = 4095;

// The root mapping of a document; ConfigError for a syntax error or a root that is no mapping.
YAML::Node parse_document(std::string_view yaml, const std::string& file);
// The whole file, which must be a regular file of at most kMaxConfigFileBytes; ConfigError naming
// it otherwise, or when it cannot be read. Never blocks on a FIFO nor reads a device.
std::string read_config_file(const std::string& path);

// Walks a document collecting problems. Every accessor reports what is wrong with the value it
// reads and returns nullopt, so a caller goes on to the next field.
class YamlReader {
 public:
  explicit YamlReader(std::string file) : file_(std::move(file)) {}

  void problem(const YAML::Node& at, const std::string& field, const std::string& message);
  void problem(int line, const std::string& field, const std::string& message);

  // Every key must be known: a typo must not silently become a default. A key given twice would
  // silently lose one of its values, so that is refused too.
  void only_keys(const YAML::Node& map, const std::string& path,
                 std::initializer_list<std::string_view> known);
  // A mapping that is present must be a mapping.
  bool mapping(const YAML::Node& node, const std::string& field);
  // The list under `key`; nullopt when absent or (reported) not a list.
  std::optional<YAML::Node> list(const YAML::Node& map, const char* key, const std::string& path);
  std::optional<std::string> string(const YAML::Node& map, const char* key, const std::string& path,
                                    bool required);
  std::optional<Integer> integer_text(const YAML::Node& node, const std::string& field);
  std::optional<std::int64_t> integer(const YAML::Node& node, const std::string& field,
                                      std::int64_t min, std::int64_t max);
  std::optional<std::int64_t> integer(const YAML::Node& map, const char* key,
                                      const std::string& path, std::int64_t min, std::int64_t max,
                                      bool required = false);
  std::optional<bool> boolean(const YAML::Node& map, const char* key, const std::string& path);
  // A SocketCAN interface name the kernel accepts (dev_valid_name: 1..15 bytes, not "." or "..",
  // no '/', ':', whitespace or NUL): a bad one would otherwise fail only when the bus is opened.
  std::optional<std::string> interface_name(const YAML::Node& map, const char* key,
                                            const std::string& path, bool required);
  // A filesystem path the kernel accepts: at most kMaxPathBytes, no NUL byte (which the system
  // call would silently cut the path at).
  std::optional<std::string> file_path(const YAML::Node& map, const char* key,
                                       const std::string& path, bool required);

  const std::vector<ConfigProblem>& problems() const { return problems_; }
  // Throws ConfigError with every problem found, if there is any.
  void finish() const;

 private:
  std::string file_;
  std::vector<ConfigProblem> problems_;
};

}  // namespace canbridge::config
