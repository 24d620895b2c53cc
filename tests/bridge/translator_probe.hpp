// Drives a CobIdTranslator from the surface side in tests: every (module, frame) it emits.
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

#include "routing/cob_id_translator.hpp"

namespace canbridge::bridge::testing {

inline std::vector<std::pair<std::size_t, can::Frame>> routes(CobIdTranslator& translator,
                                                              const can::Frame& frame) {
  std::vector<std::pair<std::size_t, can::Frame>> out;
  translator.to_modules(frame, [&](std::size_t m, const can::Frame& g) { out.emplace_back(m, g); });
  return out;
}

}  // namespace canbridge::bridge::testing
