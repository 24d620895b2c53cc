#include "routing/id_profile.hpp"

#include <array>

namespace canbridge::bridge {
namespace {

namespace cob = canopen::cob;

// The CiA 301 predefined connection set, which every profile keeps for slot 0.
std::vector<ProfileCobId> cia301_ids() {
  return {{cob::emcy, "EMCY"},     {cob::tpdo1, "TPDO1"},   {cob::rpdo1, "RPDO1"},
          {cob::tpdo2, "TPDO2"},   {cob::rpdo2, "RPDO2"},   {cob::tpdo3, "TPDO3"},
          {cob::rpdo3, "RPDO3"},   {cob::tpdo4, "TPDO4"},   {cob::rpdo4, "RPDO4"},
          {cob::sdo_tx, "SDO tx"}, {cob::sdo_rx, "SDO rx"}, {cob::heartbeat, "heartbeat"}};
}

// docs/pdop.md section 1: every PDO COB-ID in its four toggle/continued variants, and the RPDOP
// acknowledgement of section 4 (0x680 + node), which a pdop node sends.
std::vector<ProfileCobId> pdop_ids() {
  std::vector<ProfileCobId> ids;
  for (const ProfileCobId& id : cia301_ids()) {
    const bool pdo = id.base >= cob::tpdo1 && id.base <= cob::rpdo4;
    if (!pdo) {
      ids.push_back(id);
      continue;
    }
    for (unsigned tc = 0; tc < 4; ++tc) {
      ids.push_back({static_cast<std::uint16_t>(id.base | (tc << 5)),
                     id.name + " t=" + std::to_string(tc >> 1) + " c=" + std::to_string(tc & 1)});
    }
  }
  ids.push_back({0x680, "RPDOP ack"});
  return ids;
}

// docs/sim-nodes.md "qd: extended connection set": TPDOs 1..28 fill the 0x180..0x57F PDO ranges
// around the RPDOs (slot 0 of 0x200/0x300/0x400/0x500), TPDOs 29..34 the SDO ranges' slots 1..3.
std::vector<ProfileCobId> qd_ids() {
  std::vector<ProfileCobId> ids{{cob::emcy, "EMCY"}};
  constexpr std::array<std::uint16_t, 6> kHigh = {0x5A0, 0x5C0, 0x5E0, 0x620, 0x640, 0x660};
  for (unsigned tpdo = 1; tpdo <= 34; ++tpdo) {
    std::uint16_t base = 0;
    if (tpdo <= 28) {
      const unsigned group = (tpdo - 1) / 7;
      const unsigned i = (tpdo - 1) % 7;
      base = static_cast<std::uint16_t>(0x180 + 0x100 * group + 0x20 * (i < 4 ? i : i + 1));
    } else {
      base = kHigh[tpdo - 29];
    }
    ids.push_back({base, "TPDO" + std::to_string(tpdo)});
  }
  ids.push_back({cob::rpdo1, "RPDO1"});
  ids.push_back({cob::rpdo2, "RPDO2"});
  ids.push_back({cob::rpdo3, "RPDO3"});
  ids.push_back({cob::rpdo4, "RPDO4"});
  ids.push_back({cob::sdo_tx, "SDO tx"});
  ids.push_back({cob::sdo_rx, "SDO rx"});
  ids.push_back({cob::heartbeat, "heartbeat"});
  ids.push_back({0x720, "loader boot-up"});
  return ids;
}

struct Tables {
  std::array<std::vector<ProfileCobId>, 3> ids{cia301_ids(), pdop_ids(), qd_ids()};
  std::array<std::array<bool, 0x800>, 3> addressed{};
  Tables() {
    for (std::size_t p = 0; p < ids.size(); ++p) {
      const canopen::NodeId max = max_node_id(static_cast<IdProfile>(p));
      for (const ProfileCobId& id : ids[p]) {
        for (unsigned node = 1; node <= max; ++node) addressed[p][id.base + node] = true;
      }
    }
  }
};

const Tables& tables() {
  static const Tables t;
  return t;
}

}  // namespace

const char* to_string(IdProfile profile) {
  switch (profile) {
    case IdProfile::cia301:
      return "cia301";
    case IdProfile::pdop:
      return "pdop";
    case IdProfile::qd:
      return "qd";
  }
  return "unknown";
}

std::optional<IdProfile> parse_id_profile(std::string_view text) {
  for (IdProfile p : {IdProfile::cia301, IdProfile::pdop, IdProfile::qd}) {
    if (text == to_string(p)) return p;
  }
  return std::nullopt;
}

const std::vector<ProfileCobId>& profile_cob_ids(IdProfile profile) {
  return tables().ids[static_cast<std::size_t>(profile)];
}

bool is_node_addressed(IdProfile profile, std::uint32_t cob_id) {
  return cob_id < 0x800 && tables().addressed[static_cast<std::size_t>(profile)][cob_id];
}

}  // namespace canbridge::bridge
