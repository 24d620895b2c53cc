// A simulated node's object dictionary: values addressed by index and sub-index, with the access
// checks and abort codes an SDO server reports (CiA 301).
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <string_view>
#include <system_error>
#include <vector>

namespace canbridge::sim {

enum class Access : std::uint8_t {
  ro,        // read-only; the device itself may still change the value
  wo,        // write-only
  rw,        // read-write
  constant,  // read-only and never changes
};

// CiA 301 static data types a rig file can give an object. The dictionary stores bytes; the type
// decides whether a write must match the entry's size (numbers) or may have any length (strings
// and domains, up to kMaxVariableBytes).
enum class DataType : std::uint8_t {
  boolean,
  integer8,
  integer16,
  integer32,
  integer64,
  unsigned8,
  unsigned16,
  unsigned32,
  unsigned64,
  real32,
  real64,
  visible_string,
  octet_string,
  domain,
};

// Size in bytes of a fixed-size type; 0 for strings and domains.
std::size_t fixed_size(DataType type);
inline bool is_variable_length(DataType type) {
  return fixed_size(type) == 0;
}
// "unsigned16", "domain", ... as written in rig files; nullopt for an unknown name.
std::optional<DataType> parse_data_type(std::string_view name);
const char* to_string(DataType type);

// Longest value a string or domain entry accepts; a longer download aborts with 0x05040005 (out
// of memory), like a device whose buffer is full.
inline constexpr std::size_t kMaxVariableBytes = 16 * 1024 * 1024;

struct OdEntry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  Access access = Access::ro;
  DataType type = DataType::octet_string;
  std::vector<std::uint8_t> value;    // little-endian, as on the wire
  std::vector<std::uint8_t> initial;  // restored by the NMT resets
};

// Little-endian encoding of the low `size` bytes of `value`.
std::vector<std::uint8_t> le_bytes(std::uint32_t value, std::size_t size);

// index:sub as one ordered key (the order of entries()).
constexpr std::uint32_t object_key(std::uint16_t index, std::uint8_t sub) {
  return static_cast<std::uint32_t>(index) << 8 | sub;
}

class ObjectDictionary {
 public:
  struct Read {
    std::error_code error;                // SdoAbort on failure
    std::span<const std::uint8_t> value;  // valid until the entry is next written
  };

  // Called by write() after the access and length checks pass and before the value changes; a
  // non-zero result (an SdoAbort) refuses the write. The node uses it for values with meaning,
  // e.g. a PDO COB-ID that may only change while the PDO is disabled.
  using WriteGuard =
      std::function<std::error_code(const OdEntry& entry, std::span<const std::uint8_t> data)>;
  // Called by write() after the value changed (e.g. 1017h reschedules the heartbeat).
  using WriteListener = std::function<void(const OdEntry& entry)>;

  // Adds (or replaces) an entry; its current value becomes its initial value too. A numeric
  // type's value must have exactly its size (std::invalid_argument otherwise). Without a type,
  // 1, 2, 4 and 8-byte values are UNSIGNEDn and others octet strings.
  void add(std::uint16_t index, std::uint8_t sub, Access access, DataType type,
           std::vector<std::uint8_t> value);
  void add(std::uint16_t index, std::uint8_t sub, Access access, std::vector<std::uint8_t> value);
  // Unsigned integer of `size` bytes (1, 2 or 4: UNSIGNED8/16/32).
  void add_unsigned(std::uint16_t index, std::uint8_t sub, Access access, std::uint32_t value,
                    std::size_t size);

  void set_write_guard(WriteGuard guard) { guard_ = std::move(guard); }
  void set_write_listener(WriteListener listener) { listener_ = std::move(listener); }

  const OdEntry* find(std::uint16_t index, std::uint8_t sub) const;
  bool has_object(std::uint16_t index) const;

  // Access as an SDO client gets it. Errors, in this order: object missing 0x06020000, sub-index
  // missing 0x06090011, access 0x06010001 (read of write-only) / 0x06010002 (write of read-only
  // or constant); for numeric types a longer value 0x06070012, a shorter one 0x06070013; for
  // strings and domains more than kMaxVariableBytes 0x05040005; then the write guard's verdict.
  Read read(std::uint16_t index, std::uint8_t sub) const;
  std::error_code write(std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data);

  // The device's own view: no access checks. nullopt for a missing entry or one longer than 4
  // bytes.
  std::optional<std::uint32_t> get_unsigned(std::uint16_t index, std::uint8_t sub) const;
  // Keeps the entry's size (the low bytes of `value`); returns false for a missing entry.
  bool set_unsigned(std::uint16_t index, std::uint8_t sub, std::uint64_t value);
  // Replaces the bytes without checks (a variable-length entry may change size), reusing the
  // entry's storage; false when the entry is missing.
  bool set_bytes(std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> value);

  // Every entry in index/sub-index order.
  const std::map<std::uint32_t, OdEntry>& entries() const { return entries_; }

  // Restores the initial values of the objects in [first, last] (NMT reset node: the whole
  // dictionary; reset communication: 1000h..1FFFh).
  void restore_initial(std::uint16_t first = 0x0000, std::uint16_t last = 0xFFFF);

 private:
  static std::uint32_t key(std::uint16_t index, std::uint8_t sub) { return object_key(index, sub); }
  OdEntry* find_mutable(std::uint16_t index, std::uint8_t sub);
  std::error_code locate(std::uint16_t index, std::uint8_t sub) const;

  std::map<std::uint32_t, OdEntry> entries_;
  WriteGuard guard_;
  WriteListener listener_;
};

}  // namespace canbridge::sim
