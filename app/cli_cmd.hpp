// `canbridge cmd`: raw CiA 309-3 lines to the surface's command endpoint, as CANopenNode's cocomm
// sends them, with each answer printed as it came.
#pragma once

#include <iosfwd>
#include <string>
#include <vector>

#include "app/cli_session.hpp"

namespace canbridge::cli {

// Sends each line in turn (`[<n>] ` put before one without a sequence, n its place in the list)
// and prints the lines of its answer as they arrive, each with LF for its CR LF; `lines` empty:
// reads them from `in` until its end (blank and comment-only lines are skipped). Every line is
// answered before the next is sent. Returns 0 when no answer was an error, else the exit code of
// the first error (cli_reply.hpp's exit_code_for); 4 or 5 when the endpoint stops answering.
int run_cmd(const Connect& connect, const std::vector<std::string>& lines, std::istream& in);

// The sequence number a 309-3 line starts with (`[12] ...`); -1 when it has none.
long long line_sequence(std::string_view line);

}  // namespace canbridge::cli
