// A simulated node's object dictionary: values addressed by index and sub-index, with the access
// checks and abort codes an SDO server reports (CiA 301).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <system_error>
#include <vector>

namespace canbridge::sim {

enum class Access : std::uint8_t {
  ro,        // read-only; the device itself may still change the value
  wo,        // write-only
  rw,        // read-write
  constant,  // read-only and never changes
};

struct OdEntry {
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  Access access = Access::ro;
  std::vector<std::uint8_t> value;    // little-endian, as on the wire
  std::vector<std::uint8_t> initial;  // restored by the NMT resets
};

// Little-endian encoding of the low `size` bytes of `value`.
std::vector<std::uint8_t> le_bytes(std::uint32_t value, std::size_t size);

class ObjectDictionary {
 public:
  struct Read {
    std::error_code error;                // SdoAbort on failure
    std::span<const std::uint8_t> value;  // valid until the entry is next written
  };

  // Adds (or replaces) an entry; its current value becomes its initial value too. Values are 1
  // byte or longer.
  void add(std::uint16_t index, std::uint8_t sub, Access access, std::vector<std::uint8_t> value);
  // Unsigned integer of `size` bytes (1, 2 or 4: UNSIGNED8/16/32).
  void add_unsigned(std::uint16_t index, std::uint8_t sub, Access access, std::uint32_t value,
                    std::size_t size);

  const OdEntry* find(std::uint16_t index, std::uint8_t sub) const;
  bool has_object(std::uint16_t index) const;

  // Access as an SDO client gets it. Errors, in this order: object missing 0x06020000, sub-index
  // missing 0x06090011, access 0x06010001 (read of write-only) / 0x06010002 (write of read-only
  // or constant), length differs from the entry's 0x06070010.
  Read read(std::uint16_t index, std::uint8_t sub) const;
  std::error_code write(std::uint16_t index, std::uint8_t sub, std::span<const std::uint8_t> data);

  // The device's own view: no access checks. nullopt for a missing entry or one longer than 4
  // bytes.
  std::optional<std::uint32_t> get_unsigned(std::uint16_t index, std::uint8_t sub) const;
  // Keeps the entry's size; returns false for a missing entry.
  bool set_unsigned(std::uint16_t index, std::uint8_t sub, std::uint32_t value);

  // Restores the initial values of the objects in [first, last] (NMT reset node: the whole
  // dictionary; reset communication: 1000h..1FFFh).
  void restore_initial(std::uint16_t first = 0x0000, std::uint16_t last = 0xFFFF);

 private:
  static std::uint32_t key(std::uint16_t index, std::uint8_t sub) {
    return static_cast<std::uint32_t>(index) << 8 | sub;
  }
  OdEntry* find_mutable(std::uint16_t index, std::uint8_t sub);
  std::error_code locate(std::uint16_t index, std::uint8_t sub) const;

  std::map<std::uint32_t, OdEntry> entries_;
};

}  // namespace canbridge::sim
