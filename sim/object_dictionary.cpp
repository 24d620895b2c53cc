#include "sim/object_dictionary.hpp"

#include <algorithm>
#include <stdexcept>

#include "canopen/little_endian.hpp"
#include "canopen/sdo_abort.hpp"

namespace canbridge::sim {

using canopen::SdoAbort;

std::vector<std::uint8_t> le_bytes(std::uint32_t value, std::size_t size) {
  std::vector<std::uint8_t> out(size);
  canopen::store_le(value, out);
  return out;
}

namespace {

struct TypeName {
  DataType type;
  const char* name;
  std::size_t size;
};

constexpr TypeName kTypes[] = {
    {DataType::boolean, "boolean", 1},
    {DataType::integer8, "integer8", 1},
    {DataType::integer16, "integer16", 2},
    {DataType::integer32, "integer32", 4},
    {DataType::integer64, "integer64", 8},
    {DataType::unsigned8, "unsigned8", 1},
    {DataType::unsigned16, "unsigned16", 2},
    {DataType::unsigned32, "unsigned32", 4},
    {DataType::unsigned64, "unsigned64", 8},
    {DataType::real32, "real32", 4},
    {DataType::real64, "real64", 8},
    {DataType::visible_string, "visible_string", 0},
    {DataType::octet_string, "octet_string", 0},
    {DataType::domain, "domain", 0},
};

}  // namespace

std::size_t fixed_size(DataType type) {
  for (const auto& t : kTypes) {
    if (t.type == type) return t.size;
  }
  return 0;
}

std::optional<DataType> parse_data_type(std::string_view name) {
  for (const auto& t : kTypes) {
    if (name == t.name) return t.type;
  }
  return std::nullopt;
}

const char* to_string(DataType type) {
  for (const auto& t : kTypes) {
    if (t.type == type) return t.name;
  }
  return "?";
}

void ObjectDictionary::add(std::uint16_t index, std::uint8_t sub, Access access, DataType type,
                           std::vector<std::uint8_t> value) {
  const std::size_t size = fixed_size(type);
  if (size != 0 && value.size() != size) {
    throw std::invalid_argument("object dictionary value does not have its type's size");
  }
  OdEntry entry{index, sub, access, type, value, value};
  entries_.insert_or_assign(key(index, sub), std::move(entry));
}

void ObjectDictionary::add(std::uint16_t index, std::uint8_t sub, Access access,
                           std::vector<std::uint8_t> value) {
  DataType type = DataType::octet_string;
  switch (value.size()) {
    case 1:
      type = DataType::unsigned8;
      break;
    case 2:
      type = DataType::unsigned16;
      break;
    case 4:
      type = DataType::unsigned32;
      break;
    case 8:
      type = DataType::unsigned64;
      break;
    default:
      break;
  }
  add(index, sub, access, type, std::move(value));
}

void ObjectDictionary::add_unsigned(std::uint16_t index, std::uint8_t sub, Access access,
                                    std::uint32_t value, std::size_t size) {
  if (size != 1 && size != 2 && size != 4) {
    throw std::invalid_argument("UNSIGNED entries are 1, 2 or 4 bytes");
  }
  add(index, sub, access, le_bytes(value, size));
}

const OdEntry* ObjectDictionary::find(std::uint16_t index, std::uint8_t sub) const {
  const auto it = entries_.find(key(index, sub));
  return it == entries_.end() ? nullptr : &it->second;
}

OdEntry* ObjectDictionary::find_mutable(std::uint16_t index, std::uint8_t sub) {
  const auto it = entries_.find(key(index, sub));
  return it == entries_.end() ? nullptr : &it->second;
}

bool ObjectDictionary::has_object(std::uint16_t index) const {
  const auto it = entries_.lower_bound(key(index, 0));
  return it != entries_.end() && it->second.index == index;
}

std::error_code ObjectDictionary::locate(std::uint16_t index, std::uint8_t sub) const {
  if (find(index, sub) != nullptr) return {};
  return has_object(index) ? SdoAbort::no_sub_index : SdoAbort::no_object;
}

ObjectDictionary::Read ObjectDictionary::read(std::uint16_t index, std::uint8_t sub) const {
  if (const auto error = locate(index, sub)) return {error, {}};
  const OdEntry& entry = *find(index, sub);
  if (entry.access == Access::wo) return {SdoAbort::read_write_only, {}};
  return {{}, entry.value};
}

std::error_code ObjectDictionary::write(std::uint16_t index, std::uint8_t sub,
                                        std::span<const std::uint8_t> data) {
  if (const auto error = locate(index, sub)) return error;
  OdEntry& entry = *find_mutable(index, sub);
  if (entry.access == Access::ro || entry.access == Access::constant) {
    return SdoAbort::write_read_only;
  }
  const std::size_t size = fixed_size(entry.type);
  if (size != 0 && data.size() > size) return SdoAbort::length_too_high;
  if (size != 0 && data.size() < size) return SdoAbort::length_too_low;
  if (size == 0 && data.size() > kMaxVariableBytes) return SdoAbort::out_of_memory;
  if (guard_) {
    if (const auto refused = guard_(entry, data)) return refused;
  }
  entry.value.assign(data.begin(), data.end());
  if (listener_) listener_(entry);
  return {};
}

std::optional<std::uint32_t> ObjectDictionary::get_unsigned(std::uint16_t index,
                                                            std::uint8_t sub) const {
  const OdEntry* entry = find(index, sub);
  if (entry == nullptr || entry->value.size() > 4) return std::nullopt;
  return canopen::load_le32(entry->value);
}

bool ObjectDictionary::set_unsigned(std::uint16_t index, std::uint8_t sub, std::uint64_t value) {
  OdEntry* entry = find_mutable(index, sub);
  if (entry == nullptr) return false;
  canopen::store_le(value, entry->value);
  return true;
}

bool ObjectDictionary::set_bytes(std::uint16_t index, std::uint8_t sub,
                                 std::span<const std::uint8_t> value) {
  OdEntry* entry = find_mutable(index, sub);
  if (entry == nullptr) return false;
  entry->value.assign(value.begin(), value.end());
  return true;
}

void ObjectDictionary::restore_initial(std::uint16_t first, std::uint16_t last) {
  for (auto it = entries_.lower_bound(key(first, 0));
       it != entries_.end() && it->second.index <= last; ++it) {
    it->second.value = it->second.initial;
  }
}

}  // namespace canbridge::sim
