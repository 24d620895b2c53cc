// `canbridge check`: validates a configuration file of either role, and the key files it names,
// without opening an interface, a socket or a serial line, so a file can be checked before a
// restart, on another machine, or by a package's configure step.
#pragma once

#include <ostream>
#include <string>

namespace canbridge::bridge {

// Loads `path` as the role its `role:` key names and loads the keys, certificates and CAs its
// backbone.auth names, as the role would at start. Prints one summary line to `out` and returns
// 0 when all is valid; otherwise prints every problem (file:line: field: what) to `err` and
// returns 2, the exit status of a role refusing its configuration.
int check_config(const std::string& path, std::ostream& out, std::ostream& err);

}  // namespace canbridge::bridge
