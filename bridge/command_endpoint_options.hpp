// Options of the surface's CiA 309-3 command endpoint (docs/remote-access.md): where it listens,
// who may use it over TCP and with which rights, and the defaults each client session starts with.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace canbridge::bridge {

// monitor: nodes, dump/monitor, capture and SDO reads. control: everything (writes, NMT, flash,
// LSS, set-node-id). A Unix socket client is `control`: the socket file's mode and owner decide
// who connects (docs/security.md).
enum class EndpointRole : std::uint8_t { monitor, control };

struct EndpointClient {
  std::string name;   // for logs and counters
  std::string token;  // read from the configured token_file (docs/security.md); never logged
  EndpointRole role = EndpointRole::monitor;
};

struct CommandEndpointOptions {
  // The Unix socket (created mode 0660; a stale socket file is replaced). Empty: none.
  std::string unix_socket = "/run/canbridge/surface.sock";
  // TCP, off unless tcp_port is set: loopback only (docs/security.md); every client must first
  // send `auth <token>` and gets the role of the token's client.
  std::string tcp_address = "127.0.0.1";
  std::uint16_t tcp_port = 0;
  std::vector<EndpointClient> clients;
  // The defaults a session starts with (`set sdo_timeout`, `set sdo_block` change them). 500 ms
  // as CANopenNode's gateway (its help: "'sdo_timeout' is in milliseconds, 500 by default"), so a
  // script written against canopend sees its time-outs at the same moment here.
  std::chrono::milliseconds sdo_timeout{500};
  bool sdo_block = false;  // as CANopenNode's gateway: block transfer off until asked for
  // canbridge's reason after an error's reference text ("ERROR:107 #Unsupported node. node 200"):
  // for the operator, in the comment no parser reads. false: every line byte for byte as
  // CANopenNode's gateway writes it ("ERROR:107 #Unsupported node."). `set error_detail` changes
  // it for one session.
  bool error_detail = true;
  std::size_t max_clients = 16;
  // A monitor client that reads slower than the bus: frames beyond this many queued for it are
  // dropped (counted, and told to the client in one line when it catches up).
  std::size_t monitor_queue_frames = 20000;
  // The longest command line accepted (a domain written as base64 on one line).
  std::size_t max_line_bytes = 4 * 1024 * 1024;
};

}  // namespace canbridge::bridge
