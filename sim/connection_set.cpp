#include "sim/connection_set.hpp"

#include <array>

namespace canbridge::sim {

namespace {

// QD-CANopen default TPDOs of node N (0 < N < 32), seeds/003 figure 4, in its order of decreasing
// priority. Node N inherits the predefined PDO and SDO COB-IDs of nodes N+32, N+64 and N+96, and
// uses all of them for transmitting; its own four RPDOs stay the standard ones.
//
//   TPDO  source                  COB-ID       TPDO  source                  COB-ID
//    1    TxPDO 1 on N            0x180 + N     15    TxPDO 3 on N            0x380 + N
//    2    TxPDO 1 on N + 32       0x1A0 + N     16    TxPDO 3 on N + 32       0x3A0 + N
//    3    TxPDO 1 on N + 64       0x1C0 + N     17    TxPDO 3 on N + 64       0x3C0 + N
//    4    TxPDO 1 on N + 96       0x1E0 + N     18    TxPDO 3 on N + 96       0x3E0 + N
//    5    RxPDO 1 on N + 32       0x220 + N     19    RxPDO 3 on N + 32       0x420 + N
//    6    RxPDO 1 on N + 64       0x240 + N     20    RxPDO 3 on N + 64       0x440 + N
//    7    RxPDO 1 on N + 96       0x260 + N     21    RxPDO 3 on N + 96       0x460 + N
//    8    TxPDO 2 on N            0x280 + N     22    TxPDO 4 on N            0x480 + N
//    9    TxPDO 2 on N + 32       0x2A0 + N     23    TxPDO 4 on N + 32       0x4A0 + N
//   10    TxPDO 2 on N + 64       0x2C0 + N     24    TxPDO 4 on N + 64       0x4C0 + N
//   11    TxPDO 2 on N + 96       0x2E0 + N     25    TxPDO 4 on N + 96       0x4E0 + N
//   12    RxPDO 2 on N + 32       0x320 + N     26    RxPDO 4 on N + 32       0x520 + N
//   13    RxPDO 2 on N + 64       0x340 + N     27    RxPDO 4 on N + 64       0x540 + N
//   14    RxPDO 2 on N + 96       0x360 + N     28    RxPDO 4 on N + 96       0x560 + N
//   29    TxSDO on N + 32         0x5A0 + N     32    RxSDO on N + 32         0x620 + N
//   30    TxSDO on N + 64         0x5C0 + N     33    RxSDO on N + 64         0x640 + N
//   31    TxSDO on N + 96         0x5E0 + N     34    RxSDO on N + 96         0x660 + N
//
// seeds/003 lists rows 1-13 and 29-34; rows 14-28 continue its pattern. seeds/001 prints a variant
// that also takes "RxPDO 1 on N" (0x200 + N) as a TPDO; that contradicts its own statement that the
// four standard RPDOs are kept and would need 38 rows, so seeds/003 is followed.
constexpr std::array<std::uint16_t, 34> kQdTpdoBases = {
    0x180, 0x1A0, 0x1C0, 0x1E0, 0x220, 0x240, 0x260,  // PDO 1 images
    0x280, 0x2A0, 0x2C0, 0x2E0, 0x320, 0x340, 0x360,  // PDO 2 images
    0x380, 0x3A0, 0x3C0, 0x3E0, 0x420, 0x440, 0x460,  // PDO 3 images
    0x480, 0x4A0, 0x4C0, 0x4E0, 0x520, 0x540, 0x560,  // PDO 4 images
    0x5A0, 0x5C0, 0x5E0, 0x620, 0x640, 0x660,         // SDO images of N+32, N+64, N+96
};

constexpr std::array<std::uint16_t, 4> kPredefinedTpdoBases = {
    canopen::cob::tpdo1, canopen::cob::tpdo2, canopen::cob::tpdo3, canopen::cob::tpdo4};
constexpr std::array<std::uint16_t, 4> kPredefinedRpdoBases = {
    canopen::cob::rpdo1, canopen::cob::rpdo2, canopen::cob::rpdo3, canopen::cob::rpdo4};

// The qd images reach node N+96, which must stay within 1..127.
constexpr canopen::NodeId kQdMaxNodeId = 31;

bool node_in_range(NodeKind kind, canopen::NodeId node) {
  const canopen::NodeId max = kind == NodeKind::qd ? kQdMaxNodeId : canopen::kMaxNodeId;
  return node >= 1 && node <= max;
}

}  // namespace

unsigned max_tpdos(NodeKind kind) {
  return kind == NodeKind::qd ? static_cast<unsigned>(kQdTpdoBases.size())
                              : static_cast<unsigned>(kPredefinedTpdoBases.size());
}

unsigned max_rpdos(NodeKind /*kind*/) {
  return static_cast<unsigned>(kPredefinedRpdoBases.size());
}

std::optional<std::uint32_t> default_tpdo_cob_id(NodeKind kind, canopen::NodeId node,
                                                 unsigned number) {
  if (!node_in_range(kind, node) || number < 1 || number > max_tpdos(kind)) return std::nullopt;
  const std::uint16_t base =
      kind == NodeKind::qd ? kQdTpdoBases[number - 1] : kPredefinedTpdoBases[number - 1];
  return std::uint32_t{base} + node;
}

std::optional<std::uint32_t> default_rpdo_cob_id(NodeKind kind, canopen::NodeId node,
                                                 unsigned number) {
  if (!node_in_range(kind, node) || number < 1 || number > max_rpdos(kind)) return std::nullopt;
  return std::uint32_t{kPredefinedRpdoBases[number - 1]} + node;
}

}  // namespace canbridge::sim
