// The one way both roles open a pre-shared key file for the backbone (TLS psk and serial
// authentication alike): loaded now, so a problem stops the start, and watched, so keys rotate
// without a restart (docs/security.md).
#pragma once

#include <memory>
#include <stdexcept>
#include <string>

#include "backbone/key_file_watch.hpp"

namespace canbridge::bridge {

// `who` names the owner in the error ("gateway tool-gateway").
inline std::shared_ptr<backbone::KeyFileWatch> watch_key_file(const std::string& file,
                                                              const std::string& who) {
  if (file.empty()) {
    throw std::runtime_error(who + ": backbone.auth psk needs a key_file (make one with " +
                             "`openssl rand -hex 32`, see docs/security.md)");
  }
  try {
    return std::make_shared<backbone::KeyFileWatch>(file);
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(who + ": " + e.what());
  }
}

}  // namespace canbridge::bridge
