// `canbridge dump` and `canbridge capture`: the endpoint's live monitor stream, decoded in CANopen
// terms and filtered, or written as a pcap capture or a candump log.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "app/cli_session.hpp"

namespace canbridge::cli {

struct MonitorOptions {
  std::optional<unsigned> module;  // asked of the endpoint (monitor module=M)
  std::optional<unsigned> node;
  std::vector<std::string> kinds;  // canopen::FrameKind names
  bool raw = false;                // dump: candump -L lines instead of decoded text
  std::uint64_t count = 0;         // stop after this many frames shown or written; 0: never
  bool capture = false;            // capture instead of dump
  std::string file;                // capture -w
  bool candump_log = false;        // capture -l
};

std::string kind_names();
// "surface" for module 0 (frames read from the surface bus), "module<M>" otherwise: the
// interface name of candump lines.
std::string interface_name(unsigned module);

// Runs until the endpoint closes (exit 5), SIGINT/SIGTERM or `count` frames (exit 0).
int run_monitor(const Connect& connect, const MonitorOptions& options);

}  // namespace canbridge::cli
