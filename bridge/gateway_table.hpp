// The surface's table of gateways (names, sessions, what each claims, connected or not): decides
// whether a hello may bind, and which gateway a frame from the surface bus belongs to.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "bridge/gateway_claims.hpp"
#include "can/frame.hpp"

namespace canbridge::bridge {

// Why a frame from the surface bus went to no gateway.
enum class Unrouted : std::uint8_t {
  unclaimed_node,  // node-addressed (or node-specific NMT) to a node no gateway claims
  count_
};
inline constexpr std::size_t kUnroutedReasons = static_cast<std::size_t>(Unrouted::count_);

// Pure: no I/O, no clock. Gateways keep their id (0, 1, ...) by name for the surface's lifetime.
class GatewayTable {
 public:
  using GatewayId = std::uint32_t;

  // What a gateway's hello says about it. Without claims (a peer of protocol minor < 3) only its
  // modules are checked, and it gets the frames no gateway claims, as before claims existed.
  struct Hello {
    std::string name;
    std::uint64_t session_id = 0;
    std::vector<ModuleId> modules;
    std::optional<GatewayClaims> claims;
  };

  struct Admission {
    std::optional<GatewayId> id;  // nullopt: refused
    std::string refusal;          // why, naming both gateways, and what to change
    bool repeated = false;        // this name was refused for this very reason last time
  };

  explicit GatewayTable(std::string surface_name);

  // May this hello bind? Refused: a module announced twice; a gateway of the same name that is
  // connected with another session; a module, surface node id or surface COB-ID another
  // connected gateway claims. Admitted: the gateway's claims replace its previous ones and take
  // over ids that only disconnected gateways held.
  Admission admit(const Hello& hello);
  // The gateway's link is ready / ended. Only connected gateways' claims can refuse a hello.
  void set_connected(GatewayId gateway, bool connected);
  // A bound gateway's claims changed (a node moved in its live map): checked against the other
  // connected gateways like a hello's; empty when taken, else why not (the old claims stay).
  std::string update_claims(GatewayId gateway, GatewayClaims claims);

  // Where a frame from the surface bus goes.
  struct Route {
    enum Kind : std::uint8_t {
      one,        // to `gateway` only: it claims the addressed node or COB-ID
      all,        // to every gateway: broadcasts (NMT all, SYNC, TIME) and what no claim covers
                  // but is no node's (LSS, extended frames): each gateway's translator decides
      unclaimed,  // to the gateways without claims; none such: dropped, counted by `reason`
    };
    Kind kind = all;
    GatewayId gateway = 0;
    Unrouted reason = Unrouted::unclaimed_node;
  };
  Route route(const can::Frame& frame) const;

  std::optional<GatewayId> owner_of_node(NodeId surface_node) const;
  std::optional<GatewayId> owner_of_cob(std::uint32_t surface_cob) const;

  struct Entry {
    std::string name;
    std::uint64_t session_id = 0;
    std::vector<ModuleId> modules;
    std::optional<GatewayClaims> claims;
    bool connected = false;
  };
  const std::vector<Entry>& gateways() const { return entries_; }
  std::optional<GatewayId> find(std::string_view name) const;

 private:
  static constexpr std::int32_t kNobody = -1;
  std::string conflict(const Hello& hello) const;
  std::string module_conflict(const Hello& hello) const;
  std::string node_conflict(const Hello& hello) const;
  std::string cob_conflict(const Hello& hello) const;
  bool held_by_other(std::int32_t owner, const std::string& name) const;
  std::string refuse(const Hello& hello, std::string why);
  void take_claims(GatewayId gateway);

  std::string surface_name_;
  std::vector<Entry> entries_;
  // Owners by surface node id and by surface COB-ID (kNobody: unclaimed).
  std::array<std::int32_t, 128> node_owner_{};
  std::array<std::int32_t, kStandardCobIds> cob_owner_{};
  // The latest refusal of each name refused so far, to report each change once.
  std::map<std::string, std::string, std::less<>> last_refusal_;
};

}  // namespace canbridge::bridge
