// Runs a canbridge client subcommand in process and keeps what it printed.
#pragma once

#include <sstream>
#include <string>
#include <vector>

#include "app/cli_main.hpp"

namespace canbridge::test {

struct CliRun {
  int rc = -1;
  std::string out;
  std::string err;
};

inline CliRun run_cli(const std::vector<std::string>& args, bool terminal = false) {
  std::ostringstream out;
  std::ostringstream err;
  const int rc = cli::run_client(args, out, err, terminal);
  return {rc, out.str(), err.str()};
}

// The same with `input` as standard input (`cmd` without lines reads its lines there).
inline CliRun run_cli_with_input(const std::vector<std::string>& args, const std::string& input) {
  std::istringstream in(input);
  std::ostringstream out;
  std::ostringstream err;
  const int rc = cli::run_client(args, out, err, false, in);
  return {rc, out.str(), err.str()};
}

}  // namespace canbridge::test
