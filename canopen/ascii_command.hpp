// One CiA 309-3 ASCII command line (as CANopenNode's gateway reads it, plus canbridge's
// extensions: auth, nodes, flash, set node_id, monitor) parsed into a plain value, with the 309-3
// error code for a line that is not a command. The command endpoint executes the value; parsing
// knows nothing about sessions, networks or sockets.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "canopen/ascii_value.hpp"

namespace canbridge::canopen {

// CiA 309-3 internal error codes (the `ERROR:<n>` responses) and canbridge's two extensions.
enum class AsciiError : std::uint16_t {
  request_not_supported = 100,
  syntax = 101,
  internal_state = 102,
  timeout = 103,
  no_default_net = 104,
  no_default_node = 105,
  unsupported_net = 106,
  unsupported_node = 107,
  // canbridge, in the internal-error range 309-3 leaves free: the request may have been executed
  // and its answer cannot come any more (the gateway went away without one). Not a failure: the
  // operator reads the object back (docs/remote-access.md).
  outcome_unknown = 108,
  lost_connection = 201,
  authentication_required = 401,  // canbridge: TCP before `auth`
  not_permitted = 403,            // canbridge: the client's role does not allow the request
};

// The standard description ("Syntax error.") of a code.
std::string_view ascii_error_text(AsciiError error);

enum class AsciiVerb : std::uint8_t {
  none,  // blank line or comment only: nothing to answer
  read,
  write,
  nmt,
  set_network,
  set_node,
  set_sdo_timeout,
  set_sdo_block,
  help,
  lss,
  // canbridge's extensions
  auth,
  nodes,
  flash,
  set_node_id,
  monitor,
  stats,             // the role's statistics as one JSON line (docs/operations.md)
  set_error_detail,  // `set error_detail <0|1>`: canbridge's reasons after the reference text
};

enum class AsciiNmt : std::uint8_t { start, stop, preoperational, reset_node, reset_communication };

struct AsciiCommand {
  std::optional<std::uint32_t> sequence;  // `[<seq>]`: echoed in every response line
  // As written before the command; unset ones take the session's defaults.
  std::optional<std::uint32_t> net;
  std::optional<std::uint32_t> node;
  AsciiVerb verb = AsciiVerb::none;

  // read / write
  std::uint16_t index = 0;
  std::uint8_t sub = 0;
  std::optional<AsciiType> type;    // read: unset means hex
  std::vector<std::uint8_t> value;  // write: the parsed value
  AsciiNmt nmt = AsciiNmt::start;
  // set network/node/sdo_timeout/sdo_block/error_detail/node_id: the value
  std::uint32_t number = 0;
  // auth: the token; flash: the path; help: the topic ("", "datatype", "lss"); lss: the command
  std::string text;
  std::vector<std::uint32_t> args;      // lss arguments
  std::optional<std::uint32_t> module;  // monitor module=<m>
};

struct AsciiParse {
  AsciiCommand command;  // its sequence is set even when the rest failed to parse
  std::optional<AsciiError> error;
  std::string detail;  // what was wrong, for the operator
  bool ok() const { return !error; }
};

// Tokens other than values, paths and tokens (a command word, a number) are at most this long;
// longer ones are a syntax error rather than something to copy around.
inline constexpr std::size_t kMaxAsciiToken = 32;

// Parses one line without its line end (a trailing CR is ignored). `#` outside double quotes
// starts a comment. Never throws; any byte sequence gives a command or an error.
AsciiParse parse_ascii_command(std::string_view line);

// The lines of `help`, `help datatype` and `help lss` (without line ends).
std::vector<std::string> ascii_help(std::string_view topic);

}  // namespace canbridge::canopen
