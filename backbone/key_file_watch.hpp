// A key file kept current while the process runs, so pre-shared keys rotate without a restart
// (docs/security.md, "Rotation without downtime"): every use checks whether the file changed on
// disk and re-reads it then; an edit that breaks the file keeps the last good keys.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <ctime>
#include <string>
#include <vector>

#include "backbone/pre_shared_keys.hpp"

namespace canbridge::backbone {

class KeyFileWatch {
 public:
  // Loads `path` (load_key_file: permissions, owner, format); throws std::runtime_error with the
  // file's problem: a key file that cannot be used stops the start.
  explicit KeyFileWatch(std::string path);

  // The file's keys as they are now (current key first): re-read when its inode, size, mode or
  // change time moved since the last look (one stat per call). A changed file that is
  // refused (a typo, mode 0644, half written) keeps the previous keys, warned once per change.
  const std::vector<PreSharedKey>& keys();

  const std::string& path() const { return path_; }
  std::uint64_t reloads() const { return reloads_; }        // changes taken
  std::uint64_t refused_edits() const { return refused_; }  // changes refused

 private:
  struct Stamp {
    ino_t inode = 0;
    off_t size = 0;
    mode_t mode = 0;
    std::timespec changed{};  // st_ctim: content and permission changes both move it
    bool operator==(const Stamp& o) const {
      return inode == o.inode && size == o.size && mode == o.mode &&
             changed.tv_sec == o.changed.tv_sec && changed.tv_nsec == o.changed.tv_nsec;
    }
  };
  static bool stamp_of(const std::string& path, Stamp& out);

  std::string path_;
  std::vector<PreSharedKey> keys_;
  Stamp seen_{};  // the file as last looked at (taken or refused)
  std::uint64_t reloads_ = 0;
  std::uint64_t refused_ = 0;
};

}  // namespace canbridge::backbone
