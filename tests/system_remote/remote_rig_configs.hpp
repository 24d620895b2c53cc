// The remote access rig's two configuration files: the surface with its command endpoint, and
// the gateway serving rig.yaml's nodes (module 1 on vcan1, module 2 on vcan2, local ids unlike
// the surface ids), shared by the endpoint tests and the outcome tests.
#pragma once

#include <string>

#include "tests/support/temp_key_dir.hpp"

namespace canbridge::test {

// Writes surface.yaml and gateway.yaml into `keys`, both proving themselves with the key file
// `key`; the gateway connects to ${LINK_PORT} (RigOptions::port_placeholder). The endpoint's SDO
// timeout is `endpoint_sdo_timeout_ms`.
inline void write_remote_rig_configs(TempKeyDir& keys, const std::string& key,
                                     const std::string& socket_path, int endpoint_sdo_timeout_ms) {
  keys.file("surface.yaml",
            "role: surface\nname: remote-surface\nbus: vcan0\n"
            "backbone:\n  listen: 127.0.0.1:0\n  auth: {mode: psk}\n"
            "  keepalive_ms: 100\n  dead_after_ms: 400\n  retransmit_ms: 300\n"
            "gateways:\n  - name: remote-gateway\n    modules: [1, 2]\n"
            "    key_file: " +
                key +
                "\n    surface_nodes: [5-8, 42-44]\n"
                "command_endpoint:\n  unix_socket: " +
                socket_path + "\n  sdo_timeout_ms: " + std::to_string(endpoint_sdo_timeout_ms) +
                "\n  sdo_block: false\n"
                "log: {level: info, stats_interval_s: 0}\n");
  keys.file("gateway.yaml",
            "role: gateway\nname: remote-gateway\nbackbone:\n"
            "  connect: 127.0.0.1:${LINK_PORT}\n"
            "  auth: {mode: psk, key_file: " +
                key +
                ", surface: remote-surface}\n"
                "  reconnect_min_ms: 50\n  reconnect_max_ms: 200\n  keepalive_ms: 100\n"
                "  dead_after_ms: 400\n  retransmit_ms: 300\n"
                "modules:\n"
                "  - {id: 1, bus: vcan1, profile: cia301, nodes: {10: 42, 11: 43, 12: 44}}\n"
                "  - {id: 2, bus: vcan2, profile: qd, nodes: {1: 5, 2: 6, 3: 7, 4: 8}}\n"
                "lss_module: 1\n"
                "log: {level: info, stats_interval_s: 0}\n");
}

}  // namespace canbridge::test
