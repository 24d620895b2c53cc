// Typed options of each canbridge role, as validated from its YAML file.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

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
};

struct LogOptions {
  std::string level = "info";
  std::chrono::seconds stats_interval{10};  // periodic counter line; 0 disables
};

struct GatewayOptions {
  std::string name = "gateway";
  Endpoint connect;  // the surface's backbone listener
  std::chrono::milliseconds reconnect_min{100};
  std::chrono::milliseconds reconnect_max{5000};
  std::vector<ModuleOptions> modules;
  CanOptions can;
  LogOptions log;
};

struct SurfaceOptions {
  std::string name = "surface";
  Endpoint listen;
  std::string bus;  // the one SocketCAN interface the surface master sees
  CanOptions can;
  LogOptions log;
};

}  // namespace canbridge::config
