// Where the role-config tests find their YAML fixtures (tests/config/fixtures/).
#pragma once

#include <string>

namespace canbridge::test {

inline const std::string kConfigFixtures = CANBRIDGE_SOURCE_DIR "/tests/config/fixtures/";

}  // namespace canbridge::test
