#include "backbone/key_file_watch.hpp"

#include <spdlog/spdlog.h>
#include <sys/stat.h>

#include <stdexcept>
#include <utility>

namespace canbridge::backbone {

KeyFileWatch::KeyFileWatch(std::string path) : path_(std::move(path)) {
  // Stamp first: a change racing the load is then seen (and re-read) at the next use.
  stamp_of(path_, seen_);
  KeyFileResult loaded = load_key_file(path_);
  if (!loaded) throw std::runtime_error(loaded.problem->message);
  keys_ = std::move(loaded.keys);
}

bool KeyFileWatch::stamp_of(const std::string& path, Stamp& out) {
  struct stat status {};
  if (::stat(path.c_str(), &status) != 0) return false;
  out = Stamp{status.st_ino, status.st_size, status.st_mode, status.st_ctim};
  return true;
}

const std::vector<PreSharedKey>& KeyFileWatch::keys() {
  Stamp now{};
  // A file that is gone for a moment (an editor's rename-over) keeps the keys we have.
  if (!stamp_of(path_, now) || now == seen_) return keys_;
  seen_ = now;
  KeyFileResult loaded = load_key_file(path_);
  if (!loaded) {
    ++refused_;
    spdlog::warn("key file {} changed but cannot be used, keeping its previous keys: {}", path_,
                 loaded.problem->message);
    return keys_;
  }
  keys_ = std::move(loaded.keys);
  ++reloads_;
  spdlog::info("key file {} re-read: {} key(s)", path_, keys_.size());
  return keys_;
}

}  // namespace canbridge::backbone
