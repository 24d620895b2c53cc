// The I/O shell of canbridge-link-emulator: two endpoints, one Impairment per direction and the
// cut schedule on one single-threaded io_context.
#pragma once

#include "tools/link_emulator/command_line.hpp"

namespace canbridge::emulator {

// Opens the endpoints (throws on failure: startup only), prints the ready line, runs until
// SIGINT or SIGTERM, prints the final stats line. Returns the exit status (0).
int run_link_emulator(const EmulatorOptions& options);

}  // namespace canbridge::emulator
