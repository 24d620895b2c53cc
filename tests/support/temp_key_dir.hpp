// A private temporary directory of key files made at run time, so that no key is ever committed:
// configs under test name files in it, with the permissions a case needs.
#pragma once

#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <stdexcept>
#include <string>

namespace canbridge::test {

class TempKeyDir {
 public:
  TempKeyDir() {
    std::string pattern = (std::filesystem::temp_directory_path() / "canbridge-keys-XXXXXX");
    if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;  // mkdtemp makes it mode 700
  }
  ~TempKeyDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  TempKeyDir(const TempKeyDir&) = delete;
  TempKeyDir& operator=(const TempKeyDir&) = delete;

  const std::string& path() const { return path_; }

  // `name` holding one fresh random key (64 hex digits, as `openssl rand -hex 32` writes),
  // with `mode`; its path.
  std::string key(const std::string& name, mode_t mode = 0600) {
    std::random_device random;
    std::string hex;
    for (int i = 0; i < 32; ++i) {
      char byte[3];
      std::snprintf(byte, sizeof byte, "%02x", static_cast<unsigned>(random() & 0xFFu));
      hex += byte;
    }
    return file(name, hex + "\n", mode);
  }

  // `name` with `content` and `mode`; its path.
  std::string file(const std::string& name, const std::string& content, mode_t mode = 0600) {
    const std::string p = path_ + "/" + name;
    std::ofstream(p, std::ios::trunc) << content;
    if (::chmod(p.c_str(), mode) != 0) throw std::runtime_error("chmod failed: " + p);
    return p;
  }

 private:
  std::string path_;
};

}  // namespace canbridge::test
