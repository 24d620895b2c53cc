// Raises the process's soft limit on open files to its hard limit: a listener under a connection
// flood must not run out of descriptors (accept fails with EMFILE) before admission control
// closes the flood's connections.
#pragma once

#include <cstdint>

namespace canbridge::bridge {

// Returns the soft limit now in force (unchanged if it could not be raised).
std::uint64_t raise_open_file_limit();

}  // namespace canbridge::bridge
