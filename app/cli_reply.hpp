// The endpoint's response lines (docs/remote-access.md) as values for the client subcommands:
// sequence prefixes, errors with the exit code each one means, progress, node rows and monitor
// frames. Pure text in, values out.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "can/frame.hpp"

namespace canbridge::cli {

// Exit codes of every client subcommand (DESIGN of issue 16, docs/remote-access.md).
namespace exit_code {
inline constexpr int ok = 0;
inline constexpr int abort = 1;        // SDO abort or another refusal: code and text printed
inline constexpr int usage = 2;        // bad arguments, unreadable files
inline constexpr int unknown = 3;      // unknown node or network
inline constexpr int timeout = 4;      // no answer in time (endpoint, gateway or node)
inline constexpr int unreachable = 5;  // endpoint unreachable, refused, or it closed on us
// The request may have been executed, its answer lost (309-3 error 108): read the object back.
inline constexpr int outcome_unknown = 6;
}  // namespace exit_code

// The rest of `line` after "[<seq>] " when it answers request `seq`; nullopt otherwise.
std::optional<std::string_view> answer_to(std::string_view line, unsigned seq);

// "ERROR:0x06020000 #text" (an SDO abort) or "ERROR:107 #text" (a CiA 309-3 error).
struct ErrorReply {
  bool sdo_abort = false;
  std::uint32_t code = 0;
  std::string text;  // after '#', may be empty
};
std::optional<ErrorReply> parse_error(std::string_view rest);

// The exit code an error stands for: 106/107 unknown net/node -> 3; 103 and abort 0x05040000
// (timeouts) -> 4; 401/403 (refused) and 201 (the node's gateway is not connected) -> 5; 108
// (outcome unknown) -> 6; anything else -> 1.
int exit_code_for(const ErrorReply& error);
// "SDO abort 0x06020000: <the endpoint's text>", or without a text "SDO abort: <canopen::SdoAbort's
// message, which names the code>"; "error 107: <text>" for CiA 309-3 errors.
std::string describe(const ErrorReply& error);

// "PROGRESS <step> <done> <total>"; the step may contain spaces.
struct Progress {
  std::string step;
  std::uint64_t done = 0;
  std::uint64_t total = 0;
};
std::optional<Progress> parse_progress(std::string_view rest);

// "node net=1 module=0 ... emcy=-": the key=value fields after "node", in order.
using NodeRow = std::vector<std::pair<std::string, std::string>>;
std::optional<NodeRow> parse_node_row(std::string_view rest);
// "gateway name=<g> state=down" after a `nodes` answer's rows: that gateway could not be asked,
// its rows are the surface's own, lost. The gateway's name and state, in the line's order.
std::optional<NodeRow> parse_gateway_state(std::string_view rest);
std::string field(const NodeRow& row, std::string_view key);  // "" when absent

// "FRAME <unix_us> <module> <dir> <canid>#<data>": dir '>' from a module, '<' from the surface
// bus. frame.timestamp holds unix_us.
struct MonitorFrame {
  can::Frame frame;
  unsigned module = 0;
  char dir = '>';
};
std::optional<MonitorFrame> parse_monitor_frame(std::string_view line);
// "DROPPED <n>": frames the endpoint dropped because this client fell behind.
std::optional<std::uint64_t> parse_dropped(std::string_view line);

}  // namespace canbridge::cli
