// The operator subcommands of the canbridge executable (nodes, sdo, nmt, set-node-id, flash, dump,
// capture, stats, cmd): clients of a running surface's command endpoint, parsed with CLI11.
#pragma once

#include <iosfwd>
#include <string>
#include <string_view>
#include <vector>

namespace canbridge::cli {

// True for the names run_client handles (parse_command_line, app/command_line.cpp, dispatches on
// it).
bool is_client_command(std::string_view name);
// True for the options all operator commands share that take a value (--endpoint, -c, ...):
// they may stand before the command's name, and the word after them is their value.
bool is_client_option_with_value(std::string_view option);

// Runs one subcommand; `args`: argv without the program (the common options may come first).
// Returns the exit code (cli_reply.hpp's exit_code). `terminal`: `out` is a terminal (progress bar,
// not lines).
int run_client(const std::vector<std::string>& args, std::ostream& out, std::ostream& err,
               bool terminal);
// The same with `in` for `cmd`'s lines from standard input.
int run_client(const std::vector<std::string>& args, std::ostream& out, std::ostream& err,
               bool terminal, std::istream& in);

}  // namespace canbridge::cli
