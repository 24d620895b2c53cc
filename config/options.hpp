// Typed options of each canbridge role, as validated from its YAML file.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "bridge/command_endpoint_options.hpp"
#include "bridge/gateway_remote_options.hpp"
#include "bridge/surface_remote_options.hpp"
#include "routing/id_profile.hpp"
#include "routing/pdop_reassembler.hpp"
#include "routing/pdop_segmenter.hpp"
#include "routing/rpdop_relay.hpp"

namespace canbridge::config {

struct Endpoint {
  std::string host;
  std::uint16_t port = 0;
  std::string to_string() const { return host + ":" + std::to_string(port); }
};

// Tuning shared by every SocketCAN bus a process opens.
struct CanOptions {
  std::size_t receive_buffer_bytes = 16u << 20;  // absorbs bursts while the loop is busy
  std::size_t transmit_queue_frames = 8192;
};

struct ModuleOptions {
  std::uint32_t id = 0;
  std::string bus;  // SocketCAN interface name, e.g. vcan1
  // (local node id, surface node id); the default mapping when the file gives none.
  std::vector<std::pair<std::uint8_t, std::uint8_t>> nodes;
  bool default_nodes = true;
  // How the module bus lays out node-addressed COB-IDs (docs/id-profiles.md).
  bridge::IdProfile profile = bridge::IdProfile::cia301;
  // Under backlog, a queued PDO is replaced by a newer value of the same COB-ID (counted);
  // false keeps every PDO in order and drops (counted) only when the queue is full.
  bool conflate_pdos = true;
  // A node whose heartbeat is silent this long is reported lost to the surface; unset: three
  // times the node's own heartbeat interval, as observed (docs/canopen-bridging.md).
  std::optional<std::chrono::milliseconds> heartbeat_lost_after;
  // Two seconds after start the gateway asks the mapped ids it has not heard from whether they
  // are there (1000h:00; qd: 1F57h:01), so that nodes booted before it are listed
  // (docs/remote-access.md, "census"); false: no frame on this bus the gateway was not asked for.
  bool census = true;
  // profile pdop only (`pdop:` block; docs/pdop.md section 5): packets cross the backbone whole
  // (reassemble false: fragment by fragment), with these limits in both directions.
  bool reassemble_pdop = true;
  bridge::PdopReassemblerOptions pdop_reassembly;
  bridge::PdopSegmenterOptions pdop_segmentation;
};

// A serial backbone line: 8N1, no flow control unless the cable carries RTS/CTS.
struct SerialLineOptions {
  std::string device;  // /dev/ttyS1, /dev/ttyUSB0, a pty path, ...
  unsigned baud = 115200;
  bool hardware_flow_control = false;
  // Surface only: the configured gateway (AcceptedGatewayOptions::name) this line serves; its
  // key authenticates the line. Empty on the gateway (one line, to the surface).
  std::string gateway;
};

// How a role proves who it is on the backbone and checks its peers (docs/security.md). The
// loader requires `backbone.auth.mode`: plain operation is never a default.
enum class AuthMode {
  psk,  // TLS 1.3 with an external pre-shared key on TCP; challenge-response + MACs on serial
  certificates,  // TLS 1.3 with certificates of a private CA on TCP (serial lines still use PSK)
  plain,         // nothing proven: a lab bench on loopback only; warned at start
};

struct AuthOptions {
  AuthMode mode = AuthMode::psk;
  // Gateway, psk: its key file (current key first; two during rotation).
  std::string key_file;
  // Gateway: the surface's identity (its certificate's name; the name in its serial proofs).
  std::string surface = "surface";
  // certificates: this end's certificate chain and private key (PEM; the key checked like a key
  // file), and the private CA that signed the peers' certificates.
  std::string certificate_file;
  std::string private_key_file;
  std::string ca_file;
  // Serial lines: bytes of MAC per sealed message, 16 or 32; both ends must agree.
  std::size_t mac_tag_bytes = 16;
};

// Surface: how many strangers the TCP listener entertains, so a flood cannot keep a configured
// gateway out or grow memory without bound.
struct AdmissionOptions {
  // Connections whose handshake is in progress; a new connection beyond this closes the oldest.
  std::size_t max_pending_handshakes = 32;
  // A connection that has not completed its handshake (TLS, then the session hello) in this
  // time is closed.
  std::chrono::milliseconds handshake_timeout{2000};
  // Authenticated links at once; 0: four per configured gateway plus eight.
  std::size_t max_links = 0;
};

// Surface: one gateway it accepts. Only configured gateways are ever bound, and each only to
// the modules, surface node ids and COB-IDs written here.
struct AcceptedGatewayOptions {
  std::string name;  // its identity: TLS PSK identity or certificate name, and its hello's name
  std::vector<std::uint32_t> modules;
  // The surface node ids it may serve; empty: the default mapping of its modules (32 x module
  // id + 1..31).
  std::vector<std::uint8_t> surface_nodes;
  // psk (TCP or serial): the key file this gateway shares with the surface.
  std::string key_file;
};

// Session behaviour, shared by both roles (see backbone/session.hpp for the semantics).
struct SessionTuning {
  std::chrono::milliseconds keepalive{500};
  std::chrono::milliseconds dead_after{2000};  // must exceed keepalive
  std::chrono::milliseconds retransmit{1000};
  // No reliable frame older than this (from when it was read off its bus) is sent or resent:
  // it is dropped, counted, and an SDO request among them answered with an abort at the surface.
  // Must exceed retransmit.
  std::chrono::milliseconds reliable_max_age{4000};
  std::size_t resend_buffer_messages = 4096;
  std::size_t resend_buffer_bytes = 4u << 20;
  // Upper bound of one write; 0 (the default): derived from the link, 16384 on TCP and about
  // 50 ms of line time on a serial line (576 bytes at 115200 bit/s), so an urgent frame never
  // waits long behind a write (bridge::make_tuning).
  std::size_t max_write_bytes = 0;
  // Frames waiting for the link, per peer: reliable ones are never dropped once queued (a full
  // queue refuses, counted and reported); process data is conflated or dropped.
  std::size_t queue_reliable_frames = 1u << 16;
  std::size_t queue_process_frames = 1u << 14;
  // Process data that may be conflated (`conflate_pdos`) is conflated only once the oldest queued
  // frame of its COB-ID has waited this long: the link has fallen behind. A burst the link can
  // carry crosses whole, in order. 0: conflate whenever a value is still queued.
  std::chrono::milliseconds conflate_after{200};
  // COBS + CRC-32C framing on TCP links too, for a TCP path that can corrupt bytes (a serial-to-
  // Ethernet converter, a radio bridge). Both ends must agree.
  bool tcp_crc_framing = false;
};

// The optional Prometheus endpoint (`metrics: {listen: 127.0.0.1:9464}`): loopback only.
struct MetricsOptions {
  Endpoint listen;
};

struct LogOptions {
  std::string level = "info";
  std::chrono::seconds stats_interval{10};  // periodic counter line; 0 disables
};

struct GatewayOptions {
  std::string name = "gateway";
  // Exactly one transport: a TCP connection to the surface's listener, or a serial line.
  Endpoint connect;
  std::optional<SerialLineOptions> serial;
  AuthOptions auth;
  SessionTuning session;
  std::chrono::milliseconds reconnect_min{100};
  std::chrono::milliseconds reconnect_max{5000};
  std::vector<ModuleOptions> modules;
  // The one module LSS (0x7E5/0x7E4) is routed to; unset: LSS reaches no module. The command
  // line's --lss-module overrides it.
  std::optional<std::uint32_t> lss_module;
  // The services it runs for the surface's remote access (`remote:` block).
  bridge::GatewayRemoteOptions remote;
  CanOptions can;
  LogOptions log;
  // `stats_endpoint: /run/canbridge/gateway.sock`: a Unix socket answering `stats` (canbridge
  // stats --endpoint); empty: none.
  std::string stats_endpoint;
  std::optional<MetricsOptions> metrics;  // unset: no metrics endpoint
};

struct SurfaceOptions {
  std::string name = "surface";
  // Where gateways connect over TCP (empty host: no listener), and one serial line per gateway
  // reached over a serial backbone. At least one of the two.
  Endpoint listen;
  std::vector<SerialLineOptions> serial;
  AuthOptions auth;
  AdmissionOptions admission;
  // The gateways this surface accepts (at least one).
  std::vector<AcceptedGatewayOptions> gateways;
  SessionTuning session;
  bool conflate_pdos = true;  // for surface -> gateway process data, as ModuleOptions
  // RPDOP from the surface master to pdop nodes, taken by the surface (`pdop:` block).
  bridge::RpdopRelayOptions rpdop_relay;
  std::string bus;  // the one SocketCAN interface the surface master sees
  // The SDO time-out of the masters on that bus (`master_sdo_timeout_ms`): how long a request in
  // flight at a cut may wait for its answer, and the age past which no abort goes out.
  std::chrono::milliseconds master_sdo_timeout{1000};
  // The operators' CiA 309-3 command endpoint (`command_endpoint:`; tokens read from their
  // files); unset when the file has no such block: no endpoint. Then the 309-3 network numbers
  // of the modules (`networks:`) and the answer deadlines of remote access.
  std::optional<bridge::CommandEndpointOptions> command_endpoint;
  bridge::SurfaceRemoteOptions remote;
  CanOptions can;
  LogOptions log;
  std::optional<MetricsOptions> metrics;  // unset: no metrics endpoint
};

}  // namespace canbridge::config
