// The surface's table of gateways (names, sessions, what each claims, connected or not): decides
// whether a hello may bind, and which gateway a frame from the surface bus belongs to.
#pragma once

#include <array>
#include <bitset>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "bridge/accepted_gateway.hpp"
#include "bridge/gateway_claims.hpp"
#include "can/frame.hpp"

namespace canbridge::bridge {

// Why a frame from the surface bus went to no gateway.
enum class Unrouted : std::uint8_t {
  unclaimed_node,  // node-addressed (or node-specific NMT) to a node no gateway claims
  count_
};
inline constexpr std::size_t kUnroutedReasons = static_cast<std::size_t>(Unrouted::count_);

// Why a frame a bound gateway sent was kept off the surface bus (GatewayTable::may_send).
enum class NotItsOwn : std::uint8_t {
  master_only,     // NMT, SYNC, TIME, an LSS request: only the surface master sends those
  outside_claims,  // a COB-ID of no node the gateway's accepted claims hold
  extended,        // a 29-bit frame: no gateway translates one onto the surface
  count_
};
inline constexpr std::size_t kNotItsOwnReasons = static_cast<std::size_t>(NotItsOwn::count_);
const char* to_string(NotItsOwn reason);

// The surface COB-IDs the nodes `surface_nodes` may use on the surface under any module profile
// (the surface cannot know a module's profile; the gateway's hello claims only its own).
std::bitset<kStandardCobIds> cob_image_of(const std::bitset<128>& surface_nodes);

// Pure: no I/O, no clock. Holds the configured gateways only, each with a fixed id (its position
// in the configuration): a stranger's hello leaves no state behind.
class GatewayTable {
 public:
  using GatewayId = std::uint32_t;

  // What a gateway's hello says about it, and what its link proved. Without claims (a peer of
  // protocol minor < 3) only its modules are checked, and it gets the frames no gateway claims,
  // as before claims existed.
  struct Hello {
    std::string name;
    std::uint64_t session_id = 0;
    std::vector<ModuleId> modules;
    std::optional<GatewayClaims> claims;
    // SessionLink::authenticated_peer(): who the link proved the peer to be; empty: nothing.
    std::string authenticated_peer;
  };

  struct Admission {
    std::optional<GatewayId> id;  // nullopt: refused
    std::string refusal;          // why, naming both gateways, and what to change: the local log
    // What the peer is told: the details only when its link proved who it is, else just
    // "refused" (a stranger learns no names, modules or node ids).
    std::string to_peer;
    bool repeated = false;  // refused for this very reason last time
    // Refused for who it is (a name not configured, an identity not proven): nothing kept.
    bool stranger = false;
  };

  // `accepted`: names unique, modules and surface node ids disjoint (the loader checks it; an
  // overlap here throws std::invalid_argument). `require_authenticated_peers`: a link that
  // proved nothing binds nobody (false only for plain operation).
  GatewayTable(std::string surface_name, const std::vector<AcceptedGateway>& accepted,
               bool require_authenticated_peers = true);

  // May this hello bind? Refused: a name not configured; a name other than the one its link
  // proved; a link that proved nothing while authentication is required; a module, surface
  // node id or surface COB-ID outside the gateway's configuration; a module announced twice; a
  // gateway of the same name connected with another session; a surface COB-ID another
  // gateway's accepted claims hold (up or down: a gateway's ids stay its own while it is away).
  Admission admit(const Hello& hello);
  // The gateway's link is ready / ended.
  void set_connected(GatewayId gateway, bool connected);
  // A bound gateway's claims changed (a node moved in its live map): checked against its
  // configuration and the other gateways like a hello's; empty when taken, else why not (the
  // old claims stay).
  std::string update_claims(GatewayId gateway, GatewayClaims claims);

  // Whether `frame`, sent by bound gateway `gateway`, may go on the surface bus: its COB-ID
  // must be one of the gateway's accepted claims (without claims: its configured image). LSS
  // responses (0x7E4) pass: they come from the gateway's selected LSS module
  // (docs/canopen-bridging.md, "LSS").
  std::optional<NotItsOwn> refuses(GatewayId gateway, const can::Frame& frame) const;
  // Whether surface node `node` is one of the gateway's accepted nodes (PDO Packets, events).
  bool speaks_for(GatewayId gateway, NodeId node) const;

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
    std::vector<ModuleId> modules;  // as its latest accepted hello announced them
    std::optional<GatewayClaims> claims;
    bool connected = false;
    bool bound_once = false;  // a hello of it was ever admitted
  };
  // One entry per configured gateway, in configuration order.
  const std::vector<Entry>& gateways() const { return entries_; }
  std::optional<GatewayId> find(std::string_view name) const;

 private:
  static constexpr std::int32_t kNobody = -1;
  // What a configured gateway may serve.
  struct Allowance {
    std::vector<ModuleId> modules;
    std::bitset<128> nodes;
    std::bitset<kStandardCobIds> cobs;  // cob_image_of(nodes)
  };
  // What a bound gateway's accepted claims let it send (its allowance's image without claims).
  struct Accepted {
    std::bitset<128> nodes;
    std::bitset<kStandardCobIds> cobs;
  };
  std::string identity_problem(const Hello& hello) const;
  std::string allowance_problem(GatewayId gateway, const std::vector<ModuleId>& modules,
                                const std::optional<GatewayClaims>& claims) const;
  std::string conflict(const Hello& hello) const;
  std::string module_conflict(const Hello& hello) const;
  std::string node_conflict(const Hello& hello) const;
  std::string cob_conflict(const Hello& hello) const;
  bool held_by_other(std::int32_t owner, const std::string& name) const;
  Admission refuse(const Hello& hello, std::optional<GatewayId> gateway, std::string why);
  void take_claims(GatewayId gateway);

  std::string surface_name_;
  bool require_authenticated_peers_;
  std::vector<Entry> entries_;
  std::vector<Allowance> allowed_;         // by id
  std::vector<Accepted> accepted_;         // by id
  std::vector<std::string> last_refusal_;  // by id: the latest refusal, to report each change once
  std::string last_stranger_refusal_;      // the one latest refusal of a name not configured
  // Owners by surface node id and by surface COB-ID (kNobody: unclaimed).
  std::array<std::int32_t, 128> node_owner_{};
  std::array<std::int32_t, kStandardCobIds> cob_owner_{};
};

}  // namespace canbridge::bridge
